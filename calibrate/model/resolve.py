"""Which segments a marker set cannot place: the coordinates the markers do not see.

A frame's coordinates z (root translation and rotation, joint angles) are resolved by the
markers when no change of them leaves every marker where it is: when the Jacobian J of the
available markers' positions with respect to z has full column rank.  Its null space holds the
motions the markers cannot see.  A segment is *unresolved* when one of those motions moves it
(its twist J_s n is not zero for some null vector n); the coordinates to blame are those with a
component in the null space.

The test is exact and general (any tree, any marker set): J and the segment twists come from
Pinocchio's frame Jacobians (the same kinematics as calibrate.model.kinematics, in Pinocchio's
velocity coordinates, which differ from z only by a rotation of the root translation), at a few
random poses within the joint limits.  A singular value below ``tol`` counts as zero: by
default 5 mm of marker motion (the norm over all markers' coordinates) per radian, so that with
1 mm marker noise such a combination of coordinates would be known to no better than 0.2 rad
(11 degrees) per frame.  With the full Plug-in Gait set on models/human.urdf the smallest
singular value is about 0.02 m/rad; without a forearm's two wrist markers (LWRA, LWRB) it is
0.0003-0.002 m/rad (the finger marker alone barely turns the radius): that forearm and the hand
are reported.  A segment is reported when it is unresolved at every pose tried (a pose that is
singular by chance, such as a straight elbow, does not make it unresolved).

A segment without markers can still be resolved through those below it: the talus of the
human model carries none, but the ankle and subtalar angles both move the calcaneus markers.

:func:`resolve` also picks coordinates to *lock* so that the rest are resolved: going from the
root outwards (the model's DoF order), a coordinate is kept when it adds to the rank of the
kept ones, else locked.  With one marker on a thigh, for example, hip flexion and adduction are
kept and the thigh's axial rotation is locked.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from .model import Joint, Model

__all__ = ["Resolution", "UnresolvedSegment", "carried_joint", "carried_root", "carry_refusal", "line_root_holds",
           "resolve", "resolve_carrying", "root_firmness", "root_group", "unplaced_frames", "unresolved"]

TOL = 5e-3  # m per rad (or per m of root translation): singular values below this count as zero
MOVES = 0.1  # a segment moves along the null space when its twist there exceeds this (rad, or m, per unit motion)
SHARE = 0.05  # a coordinate has a share in the null space when its component exceeds this (of a unit vector)
ON_LINE = 0.015  # m: the root's markers lie on one line when none is further than this from it (line_root_holds)
MIDLINE = 0.025  # m: a joint of the root lies on its midline when its centre is this near the markers' middle along it
ALONG = np.cos(np.radians(25.0))  # a DoF turns about the markers' line when its axis is within 25 deg of it
# m per rad (or per m): how firmly a marked branch must place a markerless root it carries (carried_root): as a
# segment's own three markers do (C7, CLAV and STRN place human.urdf's trunk at 0.058; a pelvis's four markers
# 0.18-0.20; Plug-in Gait's upper-body set through the held lumbar 0.29, one leg's through the held hip 0.11), not
# through the turn of the joints beyond it (Rajagopal2016's acromia and elbows alone, both epicondyles: 0.021)
CARRY_FIRM = 0.04


@dataclass(frozen=True)
class UnresolvedSegment:
    """A segment whose pose the markers do not fix, the coordinates to blame, and why."""

    segment: str
    coordinates: tuple[str, ...]  # DoF names (or 'root') with a component in the markers' null space
    reason: str

    def to_json(self) -> dict[str, object]:
        return {"segment": self.segment, "coordinates": list(self.coordinates), "reason": self.reason}


@dataclass(frozen=True)
class Resolution:
    """What a marker set resolves of a model: unresolved segments (tree order), whether the root
    is resolved, and the coordinates to lock so that the others are resolved."""

    segments: tuple[UnresolvedSegment, ...]
    root_resolved: bool
    lock: tuple[str, ...]
    markers: tuple[str, ...]  # the model markers the test used

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.segment for s in self.segments)


def descendants(model: Model) -> dict[str, list[str]]:
    """Segment -> itself and every segment below it."""
    kids: dict[str, list[str]] = {s.name: [] for s in model.segments}
    for j in model.joints:
        kids[j.parent].append(j.child)
    out: dict[str, list[str]] = {}
    for s in reversed(model.segments):  # tree order: children after parents
        out[s.name] = [s.name] + [d for k in kids[s.name] for d in out[k]]
    return out


def _path_dofs(model: Model) -> dict[str, list[int]]:
    """Segment -> indices of the DoFs between it and the root."""
    joint_of = {j.child: j for j in model.joints}
    out: dict[str, list[int]] = {model.root: []}
    for s in model.segments[1:]:
        j = joint_of[s.name]
        out[s.name] = out[j.parent] + [model.dof_index(d) for d in j.dofs]
    return out


def _poses(model: Model, n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """`n` random joint-angle vectors inside the limits (their middle 80 %; ±90° where unlimited)."""
    lo = np.array([d.lower if np.isfinite(d.lower) else -np.pi / 2 for d in model.dofs])
    hi = np.array([d.upper if np.isfinite(d.upper) else np.pi / 2 for d in model.dofs])
    pad = 0.1 * (hi - lo)
    return [rng.uniform(lo + pad, hi - pad) for _ in range(n)]


def _jacobians(model: Model, labels: Sequence[str], angles: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Marker Jacobian (3 per marker × nv) and segment twists (6 × nv, in the segment frame), at a pose."""
    pm = model.pin
    data = pm.createData()
    q = model.pin_configuration(np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), angles)
    pin.computeJointJacobians(pm, data, q)
    pin.updateFramePlacements(pm, data)
    rows = [pin.getFrameJacobian(pm, data, pm.getFrameId(m), pin.LOCAL_WORLD_ALIGNED)[:3] for m in labels]
    J = np.vstack(rows) if rows else np.zeros((0, pm.nv))
    twists = {s.name: pin.getFrameJacobian(pm, data, pm.getFrameId(s.name), pin.LOCAL) for s in model.segments}
    return J, twists


def _null_space(J: np.ndarray, tol: float) -> np.ndarray:
    """Orthonormal basis (columns) of the directions J maps to less than `tol`."""
    n = J.shape[1]
    if J.shape[0] == 0:
        return np.eye(n)
    _, s, vt = np.linalg.svd(J, full_matrices=True)
    rank = int(np.sum(s > tol))
    return vt[rank:].T


def _full_rank(J: np.ndarray, tol: float) -> bool:
    """Whether every column of J moves the rows by more than `tol` in every combination."""
    if J.shape[0] < J.shape[1]:
        return False
    return bool(np.linalg.svd(J, compute_uv=False).min() > tol)


def _every_marker_at(model: Model, poses: int = 4, seed: int = 0) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """_jacobians of every model marker (model order) at the `poses` random poses resolve and root_firmness draw with
    `seed`: a subset of markers takes its rows (_rows), not a new evaluation."""
    return [_jacobians(model, model.marker_names, a) for a in _poses(model, poses, np.random.default_rng(seed))]


def _rows(model: Model, markers: Sequence[str], at: list[tuple[np.ndarray, dict[str, np.ndarray]]]
          ) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
    """The Jacobian rows of `markers` (in model order) from _every_marker_at's `at`."""
    idx = np.array([3 * model.marker_index(m) + k for m in markers for k in range(3)], dtype=int)
    return [(J[idx], twists) for J, twists in at]


def resolve(model: Model, labels: Iterable[str], *, locked: Iterable[str] = (), poses: int = 4, seed: int = 0,
            tol: float = TOL, _at: list | None = None, _lock: bool = True) -> Resolution:
    """Which segments of `model` the markers `labels` (trial labels; those the model lacks are
    ignored) cannot place, with the coordinates `locked` held; and a set of coordinates to lock.

    See the module docstring for the method.  Raises nothing for an empty marker set: then every
    segment, the root included, is unresolved.  (`_at`: _every_marker_at's Jacobians at the same poses; `_lock`
    False: no coordinates to lock looked for.)
    """
    present = set(labels)
    markers = tuple(m for m in model.marker_names if m in present)
    at = _rows(model, markers, _at) if _at is not None else [
        _jacobians(model, markers, a) for a in _poses(model, poses, np.random.default_rng(seed))]
    held = {model.dof_index(d) for d in locked}
    # Coordinates as a frame's (FrameLayout: the root's 6, then one per DoF), as Pinocchio's velocity.
    F = model.layout.frame
    free = [*F.root.cols.tolist(), *(F.angle(d) for d in range(model.n_dofs) if d not in held)]
    names = ["root"] * F.n_root + list(model.dof_names)
    below = descendants(model)
    path = _path_dofs(model)

    moves: dict[str, list[bool]] = {s.name: [] for s in model.segments}
    share: list[np.ndarray] = []
    Js: list[np.ndarray] = []
    for J, twists in at:
        J = J[:, free]
        Js.append(J)
        N = _null_space(J, tol)
        row = np.zeros(F.nz)
        row[free] = np.linalg.norm(N, axis=1) if N.size else 0.0
        share.append(row)
        for s in model.segments:
            T = twists[s.name][:, free]
            moves[s.name].append(bool(N.size) and float(np.linalg.norm(T @ N, 2)) > MOVES)
    unresolved_set = [s.name for s in model.segments if all(moves[s.name])]
    shares = np.array(share)
    often = (shares > SHARE).mean(axis=0) >= 0.5  # coordinates in the null space at half the poses or more

    segments: list[UnresolvedSegment] = []
    for name in unresolved_set:
        on_path = [F.angle(d) for d in path[name] if d not in held]
        blamed = [c for c in on_path if often[c]] or sorted(on_path, key=lambda c: -shares[:, c].mean())[:1]
        coord_names = (("root",) if often[F.root_pose].any() else ()) + tuple(names[c] for c in blamed)
        seen = [m for s in below[name] for m in model.segments[model.segment_index(s)].markers if m in present]
        if not seen:
            why = f"no marker on {name} or below it"
        else:
            why = (f"its markers and those below it ({', '.join(seen)}) leave "
                   f"{', '.join(coord_names) or 'some coordinates'} free: some motion moves {name} and no marker")
        segments.append(UnresolvedSegment(name, coord_names, why))

    # Coordinates to lock: keep each (root first, then the DoFs in tree order) if it adds to the rank.
    kept: list[int] = []
    lock: list[str] = []
    for k, c in enumerate(free if _lock else ()):
        trial_cols = [*kept, k]
        ok = [_full_rank(J[:, trial_cols], tol) for J in Js]
        if sum(ok) * 2 > len(ok):
            kept.append(k)
        elif c not in F.root.cols:
            lock.append(names[c])
    return Resolution(tuple(segments), model.root not in unresolved_set, tuple(lock), markers)


def unplaced_frames(model: Model, seen: np.ndarray, *, locked: Iterable[str] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, what its seen markers do not place (:func:`resolve` of the markers that frame shows, the coordinates
    `locked` held): (n_frames,) True where some motion of the root moves none of them, and (n_frames, n_dofs) True
    for each coordinate to blame for a segment they leave unplaced (every coordinate where the root is); `seen`
    (n_frames, n_markers) over the model's markers.  A trial that begins or ends with the subject outside the capture
    volume (c3d.org's sample09 walk: its last 56 frames show the right leg's markers, then none) has such frames, whose
    fit is any pose that puts those few markers in place (its pelvis 0.2 m above the floor, a hip flexed 78 deg), and
    a thigh that shows only its knee marker turns freely about the hip-knee line (the same walk's first frames: the
    left hip rotated 88-123 deg).  In a trial whose frames place the root firmly (:func:`root_firmness`, median over
    the frames at least CARRY_FIRM), a frame that places it less firmly than CARRY_FIRM counts as not placing it: the
    same walk on Rajagopal2016.osim, its frame 222 (the sacral marker, the knees, a malleolus, the toes
    and a heel: 0.034 m/rad, against 0.15 with every marker), had its hips rotated -60 and +53 deg.  One test per
    pattern of seen markers."""
    seen = np.asarray(seen, dtype=bool)
    n_frames = seen.shape[0]
    if n_frames == 0:
        return np.zeros(0, dtype=bool), np.zeros((0, model.n_dofs), dtype=bool)
    names = np.array(model.marker_names)
    locked = tuple(locked)
    patterns, inverse = np.unique(seen, axis=0, return_inverse=True)
    inverse = np.ravel(inverse)
    root = np.ones(len(patterns), dtype=bool)
    dofs = np.ones((len(patterns), model.n_dofs), dtype=bool)
    firm = np.zeros(len(patterns))
    at = _every_marker_at(model)
    for i, p in enumerate(patterns):
        if p.sum() < 3:
            continue
        r = resolve(model, names[p], locked=locked, _at=at, _lock=False)
        if r.root_resolved:
            root[i] = False
            blamed = {c for u in r.segments for c in u.coordinates}
            dofs[i] = [d in blamed for d in model.dof_names]
            firm[i] = root_firmness(model, names[p], locked=locked, _at=at)
    if np.median(firm[inverse]) >= CARRY_FIRM:
        weak = ~root & (firm < CARRY_FIRM)
        root[weak] = True
        dofs[weak] = True
    return root[inverse], dofs[inverse]


def unresolved(model: Model, labels: Iterable[str], **kwargs) -> list[UnresolvedSegment]:
    """The segments of `model` whose pose the markers `labels` cannot fix (see :func:`resolve`)."""
    return list(resolve(model, labels, **kwargs).segments)


def carried_root(model: Model, labels: Iterable[str], *,
                 locked: Iterable[str] = ()) -> UnresolvedSegment | None:
    """The root carried by the one segment below it that the markers place, where they show none on it.

    An upper-body trial (the trunk, head and arms marked, nothing on the pelvis or the legs) or a one-leg trial
    shows no marker on the root, so the root's six coordinates and the joints between it and the marked part trade
    exactly: any pose of the marked part is reached by many.  Holding those joints' DoFs at 0 loses nothing the
    markers say (every marker rides on the marked part, whose pose the root's six coordinates then reach alone) and
    makes the root ride with that part, as the base model joins them.  The marked part's top is the deepest segment
    that has every segment carrying one of `labels` on it or below it; it must not be the root (or a segment welded
    to it), and holding the DoFs on its path (those not already `locked`) must let the markers place the root.
    Returns the root's UnresolvedSegment naming those DoFs, or None where this does not hold (markers on two of the
    root's branches with none on the root: the trial's labels are not this model's)."""
    present = set(labels) & set(model.marker_names)
    top = _marked_top(model, present)
    if top is None or top in root_group(model):
        return None
    held = set(locked)
    path = [model.dof_names[d] for d in _path_dofs(model)[top]]
    hold = tuple(d for d in path if d not in held)
    if not hold or not resolve(model, present, locked=[*held, *hold]).root_resolved \
            or root_firmness(model, present, locked=[*held, *hold]) < CARRY_FIRM:
        return None
    joints = [j.name for j in model.joints if any(d in hold for d in j.dofs)]
    why = (f"no marker the trials show rides on {model.root} or on any segment but {top} and those below it: "
           f"{model.root} rides with {top}, {', '.join(hold)} held at 0 (the base model's "
           f"{', '.join(joints)} between them; the root's pose in the motion is {top}'s carried back through it)")
    return UnresolvedSegment(model.root, hold, why)


def carried_joint(model: Model, carried: UnresolvedSegment) -> Joint:
    """The joint into the marked branch a carried root rides with (carried_root's entry: the last DoF it holds)."""
    return next(j for j in model.joints if carried.coordinates[-1] in j.dofs)


def _marked_top(model: Model, present: set[str]) -> str | None:
    """The deepest segment with every segment that carries one of the markers `present` on it or below it (None:
    no such marker)."""
    marked = {mk.segment for mk in model.markers if mk.name in present}
    if not marked:
        return None
    below = descendants(model)
    top = model.root
    for s in model.segments:  # tree order: the last that holds every marked segment is the deepest
        if marked <= set(below[s.name]):
            top = s.name
    return top


def carry_refusal(model: Model, labels: Iterable[str], *, locked: Iterable[str] = ()) -> str:
    """Why the markers `labels` do not carry a markerless root (carried_root returned None), as a clause for the
    refusal's line: their branch, and how loosely it places the root where that is why; '' otherwise."""
    present = set(labels) & set(model.marker_names)
    top = _marked_top(model, present)
    if top is None or {mk.segment for mk in model.markers if mk.name in present} & root_group(model):
        return ""
    if top in root_group(model):
        return "; its markers ride on more than one branch of the model and none on the root"
    held = set(locked)
    hold = [model.dof_names[d] for d in _path_dofs(model)[top] if model.dof_names[d] not in held]
    firm = root_firmness(model, present, locked=[*held, *hold]) if hold else 0.0
    return (f"; its markers all ride on {top} and below it, but place {top}'s pose only loosely ({firm:.3f} m of "
            f"marker motion per rad, under {CARRY_FIRM:g}; three markers on {top} itself give about 0.06): add "
            f"markers on {top}")


def resolve_carrying(model: Model, labels: Sequence[str], *, locked: Iterable[str] = (),
                     carry: Sequence[str] | None = None) -> tuple[Resolution, UnresolvedSegment | None]:
    """resolve() of `labels`, and where it cannot place the root, carried_root() of `carry` (default `labels`: the
    markers whose places are known) and the resolution with its DoFs held, the root's UnresolvedSegment first and
    those DoFs first among the locks.  Returns (resolution, the carried root or None); the resolution's
    root_resolved is False where the root is neither placed nor carried."""
    held = list(locked)
    res = resolve(model, labels, locked=held)
    if res.root_resolved:
        return res, None
    carried = carried_root(model, labels if carry is None else carry, locked=held)
    if carried is None:
        return res, None
    res = resolve(model, labels, locked=[*held, *carried.coordinates])
    return replace(res, segments=(carried, *res.segments), lock=carried.coordinates + res.lock), carried


def root_firmness(model: Model, labels: Iterable[str], *, locked: Iterable[str] = (), poses: int = 4,
                  seed: int = 0, _at: list | None = None) -> float:
    """How firmly the markers `labels` place the root (m of marker motion per rad, or per m): the smallest singular
    value of the root's six Jacobian columns once every other free coordinate (not `locked`) has absorbed what it can
    (the columns projected off those coordinates' range), the median over `poses` random poses (`_at`:
    _every_marker_at's Jacobians at the same poses)."""
    present = set(labels)
    markers = tuple(m for m in model.marker_names if m in present)
    if not markers:
        return 0.0
    F = model.layout.frame
    held = {model.dof_index(d) for d in locked}
    others = [F.angle(d) for d in range(model.n_dofs) if d not in held]
    out = []
    at = _rows(model, markers, _at) if _at is not None else [
        _jacobians(model, markers, a) for a in _poses(model, poses, np.random.default_rng(seed))]
    for J, _ in at:
        root, rest = J[:, F.root.cols], J[:, others]
        if rest.shape[1]:
            u, s, _ = np.linalg.svd(rest, full_matrices=False)
            u = u[:, s > TOL]
            root = root - u @ (u.T @ root)
        out.append(float(np.linalg.svd(root, compute_uv=False).min()))
    return float(np.median(out))


def root_group(model: Model) -> set[str]:
    """The root segment and the segments welded to it (0-DoF joints, followed down from the root)."""
    rigid = {model.root}
    for j in model.joints:  # parents first: a weld chain from the root is collected in one pass
        if j.parent in rigid and not j.dofs:
            rigid.add(j.child)
    return rigid


def _neutral(model: Model) -> pin.Data:
    """Pinocchio's data at the model's neutral pose: the root at the origin, unturned (world = root frame)."""
    data = model.pin.createData()
    pin.framesForwardKinematics(model.pin, data, pin.neutral(model.pin))
    return data


def _marker_line(model: Model, names: Sequence[str], data: pin.Data) -> tuple[np.ndarray, np.ndarray] | None:
    """(middle, unit direction) of the line the markers `names` lie on at the base model's neutral pose (`data`):
    two or more, at least 2·ON_LINE apart, none further than ON_LINE from it; None otherwise."""
    if len(names) < 2:
        return None
    at = np.array([data.oMf[model.pin.getFrameId(m)].translation for m in names])
    middle = at.mean(axis=0)
    _, s, vt = np.linalg.svd(at - middle)
    u = vt[0]
    off = (at - middle) - np.outer((at - middle) @ u, u)
    return None if s[0] < 2 * ON_LINE or np.linalg.norm(off, axis=1).max() > ON_LINE else (middle, u)


def line_root_holds(model: Model, labels: Iterable[str], *,
                    locked: Iterable[str] = ()) -> tuple[UnresolvedSegment, ...]:
    """The root's turn about the line its markers lie on, held by its midline joint's DoF about that line.

    A markerless set puts two keypoints on the pelvis, both near the hip axis (Pose2Sim's ``RHip``, ``LHip``; its
    ``Hip`` between them).  The pelvis's own markers then leave its tilt to the segments it carries: the thighs turn
    about nearly the same line, and the trunk's ball turns against it, so every frame can tilt the pelvis and flex the
    trunk and the hips the other way; with the lumbar centre free the fit does (Pose2Sim's demo: hip flexion -94 to
    137 deg while balancing).  Pose2Sim's IK setup holds ``L5_S1_Flex_Ext`` for this reason; the same is done here:
    the DoF about the line (axis within 25 deg of it) of each moving joint whose parent is the root or welded to it
    and whose centre lies on the midline (within MIDLINE of the markers' middle along the line), not already
    `locked`.  The root (with its welded segments) must show two or more of `labels`, all on one line
    (_marker_line); nothing otherwise."""
    present = set(labels)
    held = set(locked)
    rigid = root_group(model)
    on_root = [m.name for m in model.markers if m.segment in rigid and m.name in present]
    data = _neutral(model)
    line = _marker_line(model, on_root, data)
    if line is None:
        return ()
    middle, u = line
    pm = model.pin
    out: list[UnresolvedSegment] = []
    for j in model.joints:
        if j.parent not in rigid or not j.dofs:
            continue
        if abs(float((data.oMi[pm.getJointId(j.dofs[0])].translation - middle) @ u)) > MIDLINE:
            continue  # a hip: on the line itself
        for d in j.dofs:
            if d in held:
                continue
            axis = data.oMi[pm.getJointId(d)].rotation @ model.dofs[model.dof_index(d)].axis
            if abs(float(axis @ u)) >= ALONG:
                why = (f"its markers ({', '.join(on_root)}) lie on one line, so its turn about that line is placed "
                       f"only through the segments it carries, where {d} and the hips' turns trade it: {d} held (as "
                       "Pose2Sim's IK setup holds its trunk's flexion), so the root turns with the segment beyond it")
                out.append(UnresolvedSegment(model.root, (d,), why))
                break
    return tuple(out)
