"""What the trial identified: each parameter's change against its prior-only uncertainty, coordinates
the trial does not show moving or drives past their limits."""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import replace
from functools import partial

import numpy as np

from ..io.labels import alias_for
from ..model.blocks import FrameLayout, perpendicular_basis
from ..model.kinematics import BallJoint
from ..model.model import Joint, Model, Parameters
from ..model.resolve import descendants
from ..model.rotations import quat_inverse, quat_matrices, quat_multiply, quat_rotvecs
from ..problem.options import Priors, ProblemOptions
from ..problem.priors import SIZED_SEGMENTS
from ..problem.problem import Problem
from .records import (
    STILL_RATIO,
    CoordinateNote,
    Identified,
    LimitNote,
    ParameterChange,
    StillNote,
    TradingLock,
    ZeroNote,
)

LIMIT_NOTE_DEG = 5.0  # a coordinate this far beyond the base model's limits ...


LIMIT_NOTE_FRACTION = 0.05  # ... in more than this fraction of the frames is noted (limit_notes)


STILL_SAMPLE = 500  # frames whose blocks still_coordinates reads (a median over frames needs no more)

UNOBSERVED = 1.0  # rad: one frame's SD of a coordinate above this, its markers do not fix it there at all

IDENTIFIED = 0.5  # posterior std / prior-only std above this (worst direction): the trial did not identify it


def coordinate_notes(model: Model, angles: np.ndarray, A: np.ndarray, options: ProblemOptions,
                     seen: Collection[str] | None = None) -> tuple[CoordinateNote, ...]:
    """still_records, then limit_records for the coordinates not already named (`options`: the problem's,
    whose locked coordinates and held axes they read; a Settings, which has the same fields, serves too;
    `seen`: the markers the trials show, see trading_joints)."""
    still = still_records(model, angles, A, options, seen)
    named = {n.coordinate for n in still}
    return still + tuple(n for n in limit_records(model, angles, options) if n.coordinate not in named)


def coordinate_spreads(model: Model, angles: np.ndarray, A: np.ndarray,
                       options: ProblemOptions) -> dict[str, tuple[float, float]]:
    """Each coordinate's (not locked) motion against what one frame's markers fix: name -> (its spread over
    the frames (SD), the median over frames of the SD with which one frame's markers fix it,
    sqrt((A_f⁻¹)_kk), A_f the frame's normal-equation block as one frame's markers alone weigh it: under their
    scatter, every frame once, pipeline._frame_blocks), in rad.

    `A`: the blocks of every frame of `angles`, or of at most STILL_SAMPLE evenly spaced ones (as
    pipeline._sampled_blocks forms them).  Frames whose markers do not fix a coordinate at all (one
    frame's SD over UNOBSERVED: a static's arm markers left out, far_joints) count for neither figure of it:
    counted, they made the median the unobserved frames' and every arm coordinate of a walk "still".  A
    coordinate no frame's markers reach is left out."""
    locked = {n for n, _ in options.lock}
    nz = A.shape[1]
    # The frames of `angles` that A's blocks belong to; then at most STILL_SAMPLE of them (a median needs no more).
    frames = np.arange(len(angles)) if len(A) == len(angles) else even_frames(len(angles), len(A))
    rows = even_frames(len(A), STILL_SAMPLE)
    A, frames = A[rows], frames[rows]
    # A ridge at one global scale: a frame (or direction) with no data gets a huge SD, not a failure.
    ridge = 1e-12 * max(float(np.max(np.abs(np.diagonal(A, axis1=1, axis2=2)), initial=0.0)), 1e-300)
    cov = np.linalg.inv(A + ridge * np.eye(nz))
    sd = np.sqrt(np.maximum(FrameLayout.angles(np.diagonal(cov, axis1=1, axis2=2)), 0.0))
    out = {}
    for k, d in enumerate(model.dofs):
        if d.name in locked:
            continue
        seen = sd[:, k] < UNOBSERVED
        if not seen.any():
            continue  # no frame's markers reach it (an unresolved segment's, locked elsewhere)
        # Every frame observed: the spread over all of them, as before; else over the observed sampled ones.
        th = angles[:, k] if seen.all() else angles[frames[seen], k]
        out[d.name] = (float(np.std(th)), float(np.median(sd[seen, k])))
    return out


def still_coordinates(model: Model, angles: np.ndarray, A: np.ndarray,
                      options: ProblemOptions) -> list[tuple[str, float, float]]:
    """The coordinates (not locked) whose estimated motion is no larger than the noise: their spread
    over the frames (SD) below STILL_RATIO times the SD with which one frame's markers fix them
    (coordinate_spreads, which says which frames count).  Such a joint did not move as far as the trial
    shows, so nothing pins its axis or its angle's zero, and the fit can trade them for noise (a still
    subtalar joint under a two-marker foot ends at its widened limit with its axis turned tens of
    degrees).  (name, spread, per-frame SD) in rad."""
    return still_of(coordinate_spreads(model, angles, A, options))


def still_of(spreads: dict[str, tuple[float, float]]) -> list[tuple[str, float, float]]:
    """The coordinates of coordinate_spreads that still_coordinates names."""
    return [(n, spread, per_frame) for n, (spread, per_frame) in spreads.items() if spread < STILL_RATIO * per_frame]


def trading_locks(model: Model, spreads: dict[str, tuple[float, float]], seen: Collection[str] | None = None,
                  locked: Collection[str] = (), turns: dict[str, float] | None = None,
                  start: dict[str, tuple[float, float]] | None = None, limit: float = math.inf
                  ) -> tuple[TradingLock, ...]:
    """The hinges to lock because the trials cannot separate their turn from a neighbour's
    (PipelineOptions.auto_hold).  A hinge qualifies that trades its turn with the next joint's across a segment
    whose markers the trials do not show (trading_joints: the subtalar beside the ankle, across the talus) and

    - moved no more than one frame's markers fix it (still_coordinates), those markers fixing it less well than
      every neighbour's coordinate there (`spreads`, coordinate_spreads at the solution); or
    - whose pair's axes the fit carried more than `limit` (rad) from the base model's (`turns`: each free hinge
      axis's angle from the base model's), the trade turning both joints through tens of degrees, while at the
      start's geometry (`start`: coordinate_spreads there, before the trade) it is the joint beyond the segment
      (the subtalar, not the ankle, as OpenSim's gait models lock it; the pronation, not the elbow), or, where
      every neighbour is on the same side of it as it is, one frame's markers fixed it less well than every
      neighbour (gait2392 without its IK setup: subtalar_angle_l 0.9 deg against the ankle's 0.5; the fit then
      turned its axis 56 deg and both angles through 43 deg SD).  Here the trials do not say which of the two
      turns, so the convention decides: neither one frame's fix (Expert1's drop jump fixes its right ankle to
      0.86 deg and the subtalar to 0.83; the ankle was locked and the subtalar's axis turned 48 deg to do its
      work), nor which one moved more for its fix (the same subject's sit-to-stand turns its ankles least), nor
      the start's poses refitted with either locked and the pair's axes at the base model's (0.4 % apart, the
      ankle's lock the cheaper on both) chose the ankle's primary role in a drop jump and in a sit-to-stand.

    Left free, both joints' turns, their axes and the foot's markers trade in every frame (pig_walk's two-marker
    feet: a static ankle at -35.6 deg against the other's -5.8, a toe marker 124 mm from its place); locked at 0
    (clipped to its range), as OpenSim's gait models lock the subtalar, the neighbour is found as any hinge.  Never
    both hinges of a pair: one still by the first rule beside a neighbour locked by the second is left free.
    `seen`, `locked`: as for trading_joints."""
    trading = trading_joints(model, seen, locked)
    out = []
    for name, (spread, per_frame) in spreads.items():
        dof = model.dofs[model.dof_index(name)]
        joint = model.joints[model.joint_index(dof.joint)]
        if dof.joint not in trading or len(joint.dofs) != 1:
            continue
        bare, neighbours = trading[dof.joint]
        if not all(n in spreads for n in neighbours):
            continue
        value = min(max(0.0, dof.lower), dof.upper)
        others = tuple(spreads[n][1] for n in neighbours)
        if spread < STILL_RATIO * per_frame and all(per_frame > o for o in others):
            out.append(TradingLock(name, value, bare, neighbours, spread, per_frame, others))
            continue
        turned = max((turns or {}).get(n, 0.0) for n in (name, *neighbours))
        if turned > limit and start is not None and all(n in start for n in (name, *neighbours)):
            first = tuple(start[n][1] for n in neighbours)
            outer = joint.parent == bare  # beyond the bare segment, as the subtalar beyond the talus
            outers = [model.joints[model.joint_index(model.dofs[model.dof_index(n)].joint)].parent == bare
                      for n in neighbours]
            if (outer and not any(outers)) or (all(o == outer for o in outers)
                                                and all(start[name][1] > o for o in first)):
                out.append(TradingLock(name, value, bare, neighbours, spread, start[name][1], first, turned))
    # Never both hinges of one pair: a hinge still beside a neighbour whose pair's axes the trade carried beyond the
    # limit is still because the neighbour did its turn (Pose2Sim's keypoint walk: the ankle still, the subtalar's
    # axis turned 30 deg to do its work); the pair's lock by the start's reading restarts the subsample from the start,
    # where the still one turns again.  Both locked, the foot was welded to the shank.
    by_turn = {n for lk in out if lk.turned for n in lk.neighbours}
    return tuple(lk for lk in out if lk.turned or lk.coordinate not in by_turn)


def zero_notes(model: Model, seen: Collection[str] | None, locked: Collection[str], still: int = 0
               ) -> tuple[ZeroNote, ...]:
    """A note per segment without seen markers between two free hinges (trading_joints: an ankle and a subtalar
    across the talus; `seen`, `locked` as there), on the joint into it: the angles' zero there rests on the priors.
    `still`: the first still trial, numbered from 1 (0: none), which --neutral would take the zero from."""
    out = []
    for name, (bare, neighbours) in trading_joints(model, seen, locked).items():
        joint = model.joints[model.joint_index(name)]
        free = [d for d in joint.dofs if d not in locked]
        beyond = [j.child for j in model.joints if j.parent == bare and any(d in neighbours for d in j.dofs)]
        if joint.child == bare and joint.kind == "hinge" and free and beyond:
            out.append(ZeroNote(free[0], bare, neighbours, beyond[0], still))
    return tuple(out)


def even_frames(n: int, count: int) -> np.ndarray:
    """At most `count` evenly spaced frames of `n`, the first and the last included."""
    return np.unique(np.linspace(0, n - 1, min(n, count)).astype(int))


def trading_joints(model: Model, seen: Collection[str] | None = None,
                   locked: Collection[str] = ()) -> dict[str, tuple[str, tuple[str, ...]]]:
    """Joints that trade their turn with a neighbour across a segment carrying no marker the trials show (`seen`:
    those markers' names; None: every model marker): joint name -> (that segment, the neighbours' free
    coordinates).  Both joints must turn (a coordinate of each not in `locked`): the ankle beside a talus whose
    subtalar joint is free; with the subtalar locked (gait2392's and Rajagopal2016's IK setups) the talus moves
    with the calcaneus's markers and the ankle is seen as any hinge.  (Rajagopal2016's talus carries a joint-centre
    marker, LAJC, that its trials do not show.)"""
    bare = {sg.name for sg in model.segments if not any(seen is None or m in seen for m in sg.markers)}
    free = {j.name: tuple(d for d in j.dofs if d not in locked) for j in model.joints}
    out: dict[str, tuple[str, tuple[str, ...]]] = {}
    for j in model.joints:
        for seg in (j.child, j.parent):
            partners = tuple(d for o in model.joints if o.name != j.name and seg in (o.parent, o.child)
                             for d in free[o.name])
            if seg in bare and free[j.name] and partners:
                out[j.name] = (seg, partners)
                break
    return out


def still_records(model: Model, angles: np.ndarray, A: np.ndarray, options: ProblemOptions,
                  seen: Collection[str] | None = None) -> tuple[StillNote, ...]:
    """A note per coordinate that still_coordinates names, with what was done and what to do (`seen`: the markers
    the trials show, for trading_joints)."""
    trading = trading_joints(model, seen, {n for n, _ in options.lock})

    def beside(name: str) -> tuple[str, tuple[str, ...]]:
        """The markerless segment at `name`'s joint and the free coordinates of the other joints there."""
        return trading.get(model.dofs[model.dof_index(name)].joint, ("", ()))

    def ball(name: str) -> str:
        joint = model.joints[model.joint_index(model.dofs[model.dof_index(name)].joint)]
        return joint.name if joint.kind == "ball" else ""

    return tuple(StillNote(name, spread, per_frame, name in options.hold_axes, *beside(name), ball=ball(name))
                 for name, spread, per_frame in still_coordinates(model, angles, A, options))


def still_notes(model: Model, angles: np.ndarray, A: np.ndarray, options: ProblemOptions) -> tuple[str, ...]:
    """still_records as the user reads them."""
    return tuple(n.text() for n in still_records(model, angles, A, options))


def limit_records(model: Model, angles: np.ndarray, options: ProblemOptions) -> tuple[LimitNote, ...]:
    """A note per coordinate that the fit drove beyond the base model's joint limits (by more than
    LIMIT_NOTE_DEG) in more than LIMIT_NOTE_FRACTION of the frames.  A coordinate the markers cannot
    resolve (a joint that did not move, under a segment with too few markers) drifts like this, and
    the geometry around it with it; one the subject really moved past the model's range does too."""
    locked = {n for n, _ in options.lock}
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


def limit_notes(model: Model, angles: np.ndarray, options: ProblemOptions) -> tuple[str, ...]:
    """limit_records as the user reads them."""
    return tuple(n.text() for n in limit_records(model, angles, options))


def _ratio_directions(C: np.ndarray, C0: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The squared posterior/prior-only std ratios (ascending) over directions and those directions (columns, not
    normalised): the generalised eigenproblem of C against C0 on the range of C0 (None: the priors alone leave
    no direction open)."""
    ev0, U = np.linalg.eigh(0.5 * (C0 + C0.T))
    keep = ev0 > 1e-12 * max(float(ev0.max(initial=0.0)), 1e-300)  # directions the priors alone leave open
    if not keep.any():
        return None
    Wh = U[:, keep] / np.sqrt(ev0[keep])  # whitening by the prior-only covariance on its range
    ev, V = np.linalg.eigh(Wh.T @ C @ Wh)
    return ev, U[:, keep] @ (np.sqrt(ev0[keep])[:, None] * V)


def worst_ratio(C: np.ndarray, C0: np.ndarray) -> tuple[float, np.ndarray]:
    """Largest posterior/prior-only std ratio over directions, and that direction."""
    found = _ratio_directions(C, C0)
    if found is None:
        return 0.0, np.linalg.eigh(0.5 * (C0 + C0.T))[1][:, -1]
    ev, dirs = found
    return math.sqrt(max(float(ev[-1]), 0.0)), dirs[:, -1] / np.linalg.norm(dirs[:, -1])


def open_directions(C: np.ndarray, C0: np.ndarray, limit: float = IDENTIFIED) -> np.ndarray:
    """An orthonormal basis (3, k) of the directions whose posterior/prior-only std ratio is at least `limit`:
    what the trial left to the prior (worst_ratio's direction among them)."""
    found = _ratio_directions(C, C0)
    if found is None:
        return np.zeros((C.shape[0], 0))
    ev, dirs = found
    dirs = dirs[:, ev >= limit**2]
    return np.linalg.qr(dirs)[0] if dirs.shape[1] else dirs


def parameter_changes(problem: Problem, p: np.ndarray, cov: np.ndarray, prior_cov: np.ndarray,
                      placed: Sequence[int] = ()) -> list[ParameterChange]:
    """Per joint centre, hinge axis, marker and scale: change from the base model, posterior std,
    and whether the trial identified it: in its worst direction, the posterior std must be below
    IDENTIFIED times the std the priors alone would leave (else the prior holds it).  `cov` and
    `prior_cov` are over the free columns, each block's found from the problem's layout.  `placed`: the hinges a
    width placed along their axes (Problem.width_placed): where their child's markers sit along the axis follows the
    width, not a trade, so a marker's distance from its prior is judged in the rest of what the trial leaves open."""
    model = problem.model
    P = model.unpack(p)
    B = problem.base
    L = problem.layout
    out: list[ParameterChange] = []
    seg_scale = P.scale
    width_axes: dict[str, list[tuple[str, np.ndarray]]] = {}  # child segment -> (hinge, its axis in that frame)
    for ji in placed:
        j = model.joints[ji]
        a = problem.axis_direction(p, model.dof_index(j.dofs[0]))
        width_axes.setdefault(j.child, []).append((j.name, a / np.linalg.norm(a)))

    # A segment without markers (the talus) is seen only through its neighbours: its two joints trade
    # off along a curved valley that the linearised posterior SD understates (on squats the subtalar
    # axes end 5-10 deg from the truth with a 1-2 deg SD), so they are never called identified.
    trading = trading_joints(model, {mk.name for k, mk in enumerate(model.markers) if problem.seen[:, k].any()},
                             {n for n, _ in problem.settings.lock})
    blind = {name: (f"next to {seg}, which carries no markers the trials show: this joint and its neighbour trade "
                    f"off beyond what the posterior SD shows; held by the prior") for name, (seg, _) in trading.items()}

    still = set(problem.settings.hold_segments)  # no marker seen on or below: held at the base model's
    # Joint centres a joint-centre marker the trials show places (Priors.joint_marker: the lab's HJC markers, or
    # --hip-regression's virtual markers at Harrington's centres): judged against that marker, not the base model.
    tied: dict[int, list[str]] = {}
    for t in problem.joint_markers():
        if problem.seen[:, t.marker].any():
            tied.setdefault(t.joint, []).append(model.markers[t.marker].name)

    # Centres held against their parent's markers (Settings.hold_centres; Problem.held_centres): joint -> how many.
    held_against = {ji: len(mks) for ji, mks in problem.held_centres()}

    shown = {model.markers[k].segment for k in np.flatnonzero(problem.seen.any(axis=0))}
    below = descendants(model)

    def unseen(segment: str) -> str:
        k = model.segment_index(segment)
        sized = not math.isclose(float(seg_scale[k]), float(B.scale[k]), abs_tol=1e-12)
        # A markerless root riding with the marked part below it (resolve.carried_root), and what carries it there
        carrier = None if segment in shown else next(
            (j.child for j in model.joints if j.parent == segment and shown & set(below[j.child])), None)
        where = (f"no marker seen on {segment}, which rides with {carrier}" if carrier else
                 f"no marker seen on or below {segment}")
        return f"{where}: held at the base model's" + (
            f" at the subject's size (scale {float(seg_scale[k]):.3g}: the median of the segments the markers size)"
            if sized else "")

    def held(owner: str) -> tuple[Identified, str]:
        """Why a block that is not free is held (`owner`: the segment it belongs to)."""
        return (Identified.UNSEEN, unseen(owner)) if owner in still else (Identified.FIXED, "held (not free)")

    def position(group: str, i: int, name: str, owner: str, judge: Judge) -> ParameterChange:
        """The change of joint centre or marker `i` of `group` (a position in segment `owner`): the value
        and its posterior and prior-only covariance at the subject's scale (its free coordinates, see
        Problem.tangent_map: what the data see), judged by `judge`."""
        value = seg_scale[model.segment_index(owner)] * getattr(P, group)[i]
        base = getattr(B, group)[i]
        block = L.block(group, i)
        open_dir = None
        if block.held:
            std, ratio = np.full(3, np.nan), float("nan")
            status, note = held(owner)
        else:
            c = block.cols
            C, C0 = cov[np.ix_(c, c)], prior_cov[np.ix_(c, c)]
            std = 1000 * np.sqrt(np.clip(np.diag(C), 0, None))
            status, note, ratio, open_dir = judge(C, C0)
            if group == "centre" and i in held_against and status.identified:
                # Its hold ties it to its parent's markers, which the trial fixes: placed by the hold, not by the
                # trial's motion (a static's shoulders would otherwise read as identified).
                status = Identified.NO
                note = (f"held at the base model's offset from {owner}'s {held_against[i]} markers "
                        "(hold_centres), not placed by the trial")
        scaled = seg_scale[model.segment_index(owner)] * base
        change = ParameterChange(group, name, base, value, 1000 * float(np.linalg.norm(value - base)), std, status,
                                 note, ratio, beyond_scale=1000 * float(np.linalg.norm(value - scaled)))
        if block.held:
            return change
        # Its prior pulls the offset from the base model's, at the subject's scale, towards zero (Priors).
        sd = problem.marker_sd()[i] if group == "marker" else problem.settings.priors.centre
        gap = value - scaled
        off = float(np.linalg.norm(gap))
        # A marker the trial places but for some directions: how far its prior failed to hold it is read in those
        # directions (pig_walk's tibia wands sit 120-130 mm higher than the base model's, the lab's wand height, which
        # the walk fixes to 3 mm; around the shank, the direction left open, 44 and 65 mm).
        followed = []
        if open_dir is not None and group == "marker":
            for hinge, a in width_axes.get(owner, []):  # along a width-placed hinge's axis the width sets it
                w = open_dir.T @ a  # the axis in the open directions' coordinates
                if float(np.linalg.norm(w)) < 0.5:  # (the trial fixes the marker along that axis: nothing to take)
                    continue
                followed.append(hinge)
                rest = np.linalg.svd(w[None, :])[2][1:]  # the open directions' complement of the axis within them
                open_dir = open_dir @ rest.T
        along = None if open_dir is None else float(np.linalg.norm(open_dir.T @ gap))
        if followed and open_dir is not None and open_dir.shape[1] == 0:
            change = replace(change, note=change.note.removesuffix(": held by the prior")
                             + f": along {' and '.join(followed)}'s axis its place follows where the width puts "
                               f"{'that hinge' if len(followed) == 1 else 'those hinges'}")
        if group == "centre" and i in tied and change.status in (Identified.YES, Identified.ACROSS_AXIS):
            if off / sd > FAR_FROM_PRIOR:  # where the lab's (or the regression's) marker puts it: not a trade
                note = (f"placed by its joint-centre marker {', '.join(tied[i])} ({1000 * off:.0f} mm from the base "
                        f"model's at the subject's scale: where the marker puts it)")
                return replace(change, note=note)
            return change
        judged = _position_far_from_prior(change, off, sd, along)
        acromion = _acromion_on_parent(model, B, i) if group == "centre" and judged.unreliable else None
        if acromion is not None:
            judged = replace(judged, note=judged.note + (
                f"; {acromion} rides on {owner} in this model while the shoulder blade lifts it with the arm: a model "
                "with a shoulder girdle carries it on a clavicle (models/human_girdle.urdf, docs/model-format.md)"))
        return judged

    for ji, j in enumerate(model.joints):
        judge = partial(_judge_centre, model, P, j, blind.get(j.name))
        out.append(position("centre", ji, j.name, j.parent, judge))
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
        out.append(position("marker", k, mk.name, mk.segment,
                            partial(_judge_marker, bool(problem.seen[:, k].any()), mk.segment)))
    free_scales = problem.free_scales()
    at_size = free_scales.size >= SIZED_SEGMENTS  # the scales' priors centre on the subject's size
    size_cols = np.array([int(L.block("scale", k).cols[0]) for k in free_scales], dtype=int)
    for si, sg in enumerate(model.segments):
        block = L.block("scale", si)
        if block.held:
            std, ratio = np.array([np.nan]), float("nan")
            status, note = held(sg.name)
        else:
            c = int(block.cols[0])
            std = np.array([math.sqrt(max(cov[c, c], 0.0))])
            # Whether the trial sizes the segment: its scale against the subject's size (the free scales' mean), whose
            # own prior (Priors.size) the data settle from every segment at once, posterior against prior-only.  The
            # prior-only variance (a pseudo-inverse) can come out zero or a rounding below it: no ratio.
            g = np.zeros(cov.shape[0])
            g[c] = 1.0
            if at_size:
                g[size_cols] -= 1.0 / size_cols.size
            post_sd, prior_sd = _sds(g, cov, prior_cov)
            ratio = float(post_sd / prior_sd) if prior_sd > 0 else float("nan")
            status = Identified.YES if ratio < IDENTIFIED else Identified.NO
            note = "" if status.identified else "the trial barely sizes this segment: held by the prior" + (
                " at the subject's size (the segments' mean scale)" if at_size else "")
        out.append(ParameterChange("scale", sg.name, np.array([1.0]), np.array([seg_scale[si]]),
                                   float(seg_scale[si] - 1.0), std, status, note, ratio))
    # Each coordinate beside a markerless segment: its neighbours' there, one of which to lock (_far_from_prior).
    pairs = {d: partners for name, (_, partners) in trading.items()
             for d in model.joints[model.joint_index(name)].dofs}
    return [_far_from_prior(c, problem.settings.priors, pairs.get(c.item, ())) for c in out]


def segment_end(model: Model, segment: int) -> int | None:
    """The joint whose centre ends segment `segment` (index) for its length: the first joint below it in the
    model's order.  The segment runs from its own joint's centre, its frame's origin, to there.  None: a leaf."""
    name = model.segments[segment].name
    return next((j for j, jt in enumerate(model.joints) if jt.parent == name), None)


def length_differences(problem: Problem, p: np.ndarray, cov: np.ndarray,
                       prior_cov: np.ndarray) -> dict[str, tuple[float, float]]:
    """Per left/right segment pair (its name without _l / _r): the posterior SD of the difference of the two
    segments' lengths (segment_end) and the SD the priors alone would leave it, in m.  A length is the norm of its
    end's centre at the subject's scale, which is that centre's free coordinates themselves
    (ParameterLayout.tangent_map): it moves along their unit vector, and the two sides' correlation counts.  Where
    the two SDs are alike the trials do not measure the difference, the priors and the gauges set it (a foot's
    subtalar and mtp centres, which no marker places: Expert1's feet 13 % apart, 24 +- 17 mm).  A pair whose two
    ends are both held (not free) is left out."""
    from ..problem.priors import symmetry_pairs

    model, L = problem.model, problem.layout
    segments, _, _ = symmetry_pairs(model, model.parameters().centre)

    def gradient(seg: int) -> np.ndarray | None:
        j = segment_end(model, seg)
        if j is None:
            return None
        g = np.zeros(cov.shape[0])
        cols = L.cols("centre", j)
        if cols.size:
            q = p[L.scale(seg)] * p[L.centre(j)]
            g[cols] = q / max(float(np.linalg.norm(q)), 1e-12)
        return g

    out = {}
    for a, b in segments:
        ga, gb = gradient(a), gradient(b)
        if ga is None or gb is None or not (ga.any() or gb.any()):
            continue
        out[model.segments[a].name[:-2]] = _sds(ga - gb, cov, prior_cov)
    return out


def mirror_differences(problem: Problem, p: np.ndarray, cov: np.ndarray,
                       prior_cov: np.ndarray) -> dict[str, tuple[float, float]]:
    """Per left/right joint pair (its name without _l / _r): the posterior SD of the distance between the left centre
    and the mirrored right one, each at its parent's scale in its parent's frame (the report's centre_mirror_mm), and
    the SD the priors alone would leave it, in m.  The centres' free coordinates are those scaled positions
    (ParameterLayout.tangent_map), so the distance moves along its unit vector, mirrored for the right.  A pair whose
    two centres are held is left out."""
    from ..problem.priors import symmetry_pairs

    model, L = problem.model, problem.layout
    _, joints, mirror = symmetry_pairs(model, model.parameters().centre)
    out = {}
    for a, b in joints:
        ca, cb = L.cols("centre", a), L.cols("centre", b)
        if not (ca.size or cb.size):
            continue
        qa, qb = (p[L.scale(model.segment_index(model.joints[j].parent))] * p[L.centre(j)] for j in (a, b))
        d = qa - mirror * qb
        u = d / max(float(np.linalg.norm(d)), 1e-12)
        g = np.zeros(cov.shape[0])
        if ca.size:
            g[ca] += u
        if cb.size:
            g[cb] -= mirror * u
        out[model.joints[a].name[:-2]] = _sds(g, cov, prior_cov)
    return out


def _sds(g: np.ndarray, cov: np.ndarray, prior_cov: np.ndarray) -> tuple[float, float]:
    """The SDs of a quantity of gradient `g` (over the free parameters) under `cov` and under `prior_cov`."""
    return float(np.sqrt(max(g @ cov @ g, 0.0))), float(np.sqrt(max(g @ prior_cov @ g, 0.0)))


FAR_FROM_PRIOR = 3.0  # prior SDs: an axis the trial did not identify this far from the base model's is not "held"
#: rad: a hinge (or universal) axis the fit carried beyond FAR_FROM_PRIOR prior SDs from the base model's, while the
#: moving trials turn its joint through less than this (2nd to 98th percentile of the subsample's angles), is held at
#: the base model's, as a still joint's (PipelineOptions.auto_hold); a joint centre so carried, where every angle of
#: its joint turns less than this, too (pipeline._narrow_centres).  Skin turns a segment against its bone by up to
#: 4.4 deg in a walk (Benoit et al. 2006, bone pins at the knee): against a turn of 20 deg that alone tilts a fitted
#: axis by up to atan(4.4 / 20) = 12 deg, and a turn that narrow does not place an axis 30 deg from the base model's.
#: BTKData's FunctionalLHip (a left-hip trial; the right knee turned 7 deg) carried knee_r's axis 46 deg.
NARROW_TURN = math.radians(20.0)


def joint_turns(angles: np.ndarray, ball: BallJoint | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """How far a ball or universal joint turns over frames, largest first (rad): the 2nd-to-98th percentile range of
    each of its angles (`angles`: rows frames, columns its DoFs), or for a ball (`ball`: the solver's BallJoint of it)
    of its rotations' vectors about their mean rotation along each of their principal directions; and for a ball
    those directions (rows, unit, in the joint's frame: the frame its angles turn from; None otherwise).  A turn
    about one axis places the joint's centre across that axis, not along it (every point of the axis is a centre of
    that turn); a ball's angles would split one turn about an axis between their frames' axes, and read it as two."""
    a = np.asarray(angles, dtype=float)
    if ball is None or a.shape[1] != 3:
        spread = np.percentile(a, 98, axis=0) - np.percentile(a, 2, axis=0)
        return np.sort(spread)[::-1], None
    q = ball.quaternion(a)
    mean = np.linalg.eigh(q.T @ q)[1][:, -1]  # the mean rotation (Markley's: the largest eigenvector of sum q q^T)
    w = quat_rotvecs(quat_multiply(quat_inverse(mean), q))  # each frame's turn from it, in the turned frame
    w = w - np.median(w, axis=0)
    V = np.linalg.eigh(np.cov(w.T))[1]
    along = w @ V
    spread = np.percentile(along, 98, axis=0) - np.percentile(along, 2, axis=0)
    order = np.argsort(spread)[::-1]
    return spread[order], (quat_matrices(mean[None])[0] @ V[:, order]).T


def _far_from_prior(change: ParameterChange, priors: Priors, neighbours: tuple[str, ...] = ()) -> ParameterChange:
    """`change` with its note corrected where it is a hinge axis that lies more than FAR_FROM_PRIOR prior SDs
    (Priors.axis) from the base model's.  One the trial did not identify: the prior did not hold it
    there, a valley of the fit (a trade with a neighbour the data do not separate) carried it, so the
    value is not to be trusted (gait2392's ankle axis next to the markerless talus: 54 deg, 5.4 prior SDs).
    One the trial identified is no more to be trusted, as a joint centre the trial places that far is not.
    `neighbours`: the free coordinates it trades with across a markerless segment; locking the one of the pair
    that hardly moves is what finds the other (gait2392 with its IK setup's subtalar locked: its ankles within
    2-5 deg of OpenSim's IK; holding the axis instead turned the thigh 30 deg, docs/benchmarks.md).
    (A position's change includes the segment's scaling, which its prior does not count against it.)"""
    sd = math.degrees(priors.axis)
    if change.group != "axis" or not sd > 0:
        return change
    k = change.change / sd
    if k <= FAR_FROM_PRIOR:
        return change
    if change.status is Identified.YES:
        # The data turn it, and turn it where no anatomy does: skin that moves with the joint's turn (a thigh's
        # markers rolling about the femur as the knee flexes) tilts an axis fitted to them with a small posterior SD
        # (AddBiomechanics' opencap_test walk, before placeholder markers: both knees 31-41 deg, SD 3.5-3.9 deg;
        # fitted on its first half, its second half fits 9.18 mm with them, 6.97 with the knee axes held).
        sd_now = float(np.nanmax(change.std))
        note = (f"the trial turns it (posterior SD {sd_now:.1f} deg), yet {change.change:.0f} deg from the base "
                f"model's ({k:.1f} prior SDs): few joints' axes lie so far from a generic model's, while skin that "
                "moves with the joint's turn tilts an axis fitted to it with a small SD; not reliable unless the base "
                f"model is that far from this subject (--hold-axes {change.item} keeps the base model's)")
        return replace(change, unreliable=True, note=note)
    if change.status is not Identified.NO:
        return change
    why = change.note.removesuffix(": held by the prior").removesuffix("; held by the prior")
    note = (f"{why}; yet {change.change:.0f} deg from the base model's ({k:.1f} prior SDs), so the prior did not hold "
            f"it: a trade the data do not separate carried it there, and the axis is not reliable (")
    if neighbours:
        note += (f"if one of {' or '.join((change.item, *neighbours))} hardly moves (a subtalar joint in a walk), lock "
                 f"that one (--lock NAME; an OpenSim model: --ik-setup locks what the lab's IK holds) and the other's "
                 f"axis is found; ")
    note += f"--hold-axes {change.item} keeps the base model's)"
    return replace(change, unreliable=True, note=note)


ACROMION_REACH = 0.08  # m: an acromion marker this near a shoulder's centre on the segment the shoulder hangs from


def _acromion_on_parent(model: Model, base: Parameters, ji: int) -> str | None:
    """The acromion marker (Plug-in Gait's xSHO, or a label that reads as it) riding on the segment ball joint `ji`
    hangs from, within ACROMION_REACH of its centre in the base model: a shoulder without a girdle, whose acromion
    the shoulder blade carries up with the arm (models/human.urdf's; treadmill and overhead trials place such a
    shoulder 60-115 mm from the base model's, docs/benchmarks.md)."""
    j = model.joints[ji]
    if j.kind != "ball":
        return None
    for k, m in enumerate(model.markers):
        if m.segment != j.parent or np.linalg.norm(base.marker[k] - base.centre[ji]) > ACROMION_REACH:
            continue
        if m.name in ("RSHO", "LSHO") or alias_for(m.name, ("RSHO", "LSHO")) is not None:
            return m.name
    return None


def _position_far_from_prior(change: ParameterChange, off: float, sd: float,
                             along: float | None = None) -> ParameterChange:
    """`change` (a joint centre or marker) with its note corrected where it lies `off` (m) from where its prior puts
    it (the base model's, at the subject's scale), more than FAR_FROM_PRIOR prior SDs `sd`: where the trial did not
    identify it, as for an axis (_far_from_prior), the prior did not hold it there and its place is not to be
    trusted (Rajagopal's elbow_l with the elbow axes held: 153 mm, "held by the prior"); a joint centre the trial
    places there is no more to be trusted (a marker may sit anywhere the lab put it).  `along`: for a marker the
    trial left open in some directions, its distance from the prior's place in those directions, which is what is
    judged (the rest the trial placed)."""
    if along is not None and change.status is Identified.NO:
        if not sd > 0 or along / sd <= FAR_FROM_PRIOR:
            return change
        why = change.note.removesuffix(": held by the prior")
        note = (f"{why}; yet {1000 * along:.0f} mm from where its prior puts it in what the trial leaves open "
                f"({along / sd:.1f} prior SDs; {1000 * off:.0f} mm in all), so the prior did not hold it: a trade the "
                "data do not separate carried it there, and the marker's place is not reliable")
        return replace(change, unreliable=True, note=note)
    if not sd > 0 or off / sd <= FAR_FROM_PRIOR:
        return change
    if change.group == "centre" and change.status in (Identified.YES, Identified.ACROSS_AXIS):
        # The data place it, and place it where no anatomy does: skin that moves with the joint's motion (or a
        # displaced marker) carries a centre so with a small posterior SD (docs/calibration.md, "What the posterior
        # SD does not count"); gait2392's lumbar centre on its whole walk: 116 mm.
        note = (f"the trial places it (posterior SD {np.nanmax(change.std):.0f} mm), yet {1000 * off:.0f} mm from "
                f"where its prior puts it, the base model's at the subject's scale ({off / sd:.1f} prior SDs): few "
                "subjects are so far from a scaled generic model, while skin that moves with the joints or a displaced "
                "marker can carry a centre so far with a small SD; not reliable unless the base model is that far "
                "from this subject")
        return replace(change, unreliable=True, note=note)
    if change.status is not Identified.NO:
        return change
    why = change.note.removesuffix(": held by the prior").removesuffix("; held by the prior")
    why = why.removesuffix(" either: held by the prior").removesuffix(" either")
    what = "marker's place" if change.group == "marker" else "centre"
    note = (f"{why}; yet {1000 * off:.0f} mm from where its prior puts it ({off / sd:.1f} prior SDs), so the prior "
            f"did not hold it: a trade the data do not separate carried it there, and the {what} is not reliable")
    return replace(change, unreliable=True, note=note)


# (posterior, prior-only cov) -> verdict, note, worst ratio, and the directions left open (an orthonormal basis (3, k);
# None: a centre, judged as a whole)
Judge = Callable[[np.ndarray, np.ndarray], tuple[Identified, str, float, np.ndarray | None]]


def _judge_centre(model: Model, P: Parameters, j: Joint, blind: str | None, C: np.ndarray,
                  C0: np.ndarray) -> tuple[Identified, str, float, None]:
    """Whether the trial identified joint `j`'s free centre, from its posterior and prior-only covariance
    (m²) at `P`; `blind`: why a joint next to a segment without markers is never identified.  (A Judge: a
    centre is judged as a whole, no open directions.)"""
    if j.kind == "hinge":
        # Along its axis a hinge centre is a gauge: no motion moves the markers when it
        # slides there (the child's contents slide back), so the prior alone holds it.
        d = model.dof_index(j.dofs[0])
        u = next(u for u in model.urdf_joints if u.name == j.urdf_joints[0])
        a = u.rotation @ (P.axis[d] / np.linalg.norm(P.axis[d]))
        Qp = perpendicular_basis(a)
        ratio, v = worst_ratio(Qp.T @ C @ Qp, Qp.T @ C0 @ Qp)
        status = Identified.ACROSS_AXIS if ratio < IDENTIFIED else Identified.NO
        axis_txt = ", ".join(f"{x:+.2f}" for x in a)
        # Across the axis, the direction the trial leaves most to the prior (in the parent's frame, as the axis).
        across = ", ".join(f"{x:+.2f}" for x in Qp @ v)
        note = (f"along its axis ({axis_txt}) in the {j.parent} frame it is held by the prior (no motion "
                f"defines it); across the axis " + ("identified" if ratio < IDENTIFIED else
                                                     f"not identified along ({across}) either: held by the prior"))
    else:
        ratio, v = worst_ratio(C, C0)
        status = Identified.YES if ratio < IDENTIFIED else Identified.NO
        note = "" if status.identified else (f"not identified along ({', '.join(f'{x:+.2f}' for x in v)}) "
                                             f"in the {j.parent} frame: held by the prior")
    if blind is not None:
        status, note = Identified.NO, blind
    return status, note, ratio, None


def _judge_marker(seen: bool, segment: str, C: np.ndarray,
                  C0: np.ndarray) -> tuple[Identified, str, float, np.ndarray | None]:
    """Whether the trial identified a free marker offset (`seen`: in some frame) on `segment`, from its posterior
    and prior-only covariance.  A marker seen in every frame can still leave a direction of its place open: a
    tibia wand's place around the shank trades with the shank's turn about its long axis, which only the hinge
    axes fix."""
    ratio, v = worst_ratio(C, C0)
    status = Identified.YES if seen and ratio < IDENTIFIED else Identified.NO
    note = "" if status.identified else ("never seen in the trial: base model kept" if not seen else
                                         f"not identified along ({', '.join(f'{x:+.2f}' for x in v)}) in the "
                                         f"{segment} frame: held by the prior")
    return status, note, ratio, (open_directions(C, C0) if seen and not status.identified else None)
