"""Priors of the calibration problem: the pull of every parameter towards the base model, left/right
symmetry, and the joint-limit residuals."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..io.measurements import WIDTH_JOINTS, lateral_markers_of
from ..model.model import Model, Parameters


def symmetry_pairs(model: Model, centres: np.ndarray) -> tuple[list[tuple[int, int]], list[tuple[int, int]],
                                                               np.ndarray]:
    """Left/right partners by name (``X_l`` / ``X_r``): (segment index pairs, joint index pairs, mirror),
    the mirror a diagonal (3,) of ±1 that reflects a position through the sagittal plane: the lateral
    axis is the one along which the base model's paired joint centres `centres` (n_joints, 3) differ most
    (y in models/human.urdf, whose segment frames are all parallel in the neutral pose)."""
    def pairs(names: list[str]) -> list[tuple[int, int]]:
        at = {n: i for i, n in enumerate(names)}
        return [(i, at[n[:-2] + "_r"]) for i, n in enumerate(names) if n.endswith("_l") and n[:-2] + "_r" in at]

    seg = pairs([s.name for s in model.segments])
    jnt = pairs([j.name for j in model.joints])
    mirror = np.ones(3)
    if jnt:
        spread = np.sum([np.abs(centres[a] - centres[b]) for a, b in jnt], axis=0)
        mirror[int(np.argmax(spread))] = -1.0
    else:
        mirror[1] = -1.0
    return seg, jnt, mirror


#: The hinges whose Plug-in Gait lateral marker sits over the bone the flexion axis passes through (the femoral and
#: humeral epicondyles, the lateral malleolus): Priors.on_axis keeps it on a held axis.
ON_AXIS_JOINTS = ("knee", "ankle", "elbow")

#: The hinges whose centre Priors.knee_landmark and Priors.ankle_landmark hold on the axis line through their
#: anatomical landmarks: a knee by its epicondyles' markers or Plug-in Gait's KNE, an ankle by its malleoli's markers
#: (a straddling pair only: ANK alone, tried, came no nearer Plug-in Gait's own ankle centres: docs/benchmarks.md).
LANDMARK_JOINTS = ("knee", "ankle")

#: m, at the base model's scale: a hinge whose base model puts none of its landmark markers this near its axis line
#: (PAIR_OFF, as a pair's line may pass its centre) gets no landmark prior: the base model's axis passes by neither.
#: models/human.urdf's LKNE sits 1.9 mm from it, gait2392's epicondyles 11.7 mm from its fixed hinge (the best over the
#: coordinate's range), Rajagopal2016's 5.5 mm; about the ankle human.urdf's LANK 6.1 mm, Rajagopal2016's medial
#: malleolus 12.6 mm (gait2392's malleoli's line passes 31.5 mm from its ankle's axis: no pair, no rows).
LANDMARK_OFF = 0.030


def on_axis_markers(model: Model, held: Callable[[int], bool]) -> list[tuple[int, int]]:
    """(joint index, marker index) of each knee, ankle and elbow hinge of `model` (named as in models/human.urdf)
    whose DoF index `held` says is not calibrated and whose Plug-in Gait lateral marker (LKNE, RANK, LELB, ...)
    rides on the segment it hangs from: the markers Priors.on_axis keeps on their axis lines."""
    joints = {j.name: i for i, j in enumerate(model.joints)}
    out = []
    for jname, mname in lateral_markers_of(model, ON_AXIS_JOINTS):
        ji = joints[jname]
        if held(model.dof_index(model.joints[ji].dofs[0])):
            out.append((ji, model.marker_index(mname)))
    return out


#: Two markers on a hinge's parent segment that straddle its centre along its axis are the lab's anatomical
#: line for it (the femoral epicondyles about a knee, the humeral epicondyles about an elbow, the malleoli about an
#: ankle: Grood & Suntay's and the ISB's flexion axes), recognised at the base geometry, names aside: PAIR_SPAN apart
#: (m), their line within PAIR_ANGLE of the base model's axis, passing within PAIR_OFF of the centre (m), the centre
#: between them (its projection PAIR_INNER to 1 - PAIR_INNER along the way from one to the other).  Priors.pair_axis
#: pulls the calibrated axis along their line.
PAIR_SPAN = (0.04, 0.16)
PAIR_ANGLE = math.radians(35.0)
PAIR_OFF = 0.03
PAIR_INNER = 0.15


def straddle(centre: np.ndarray, axis: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> float | None:
    """How far (m) the line through markers `x1` and `x2` passes from a hinge's `centre`, where the two straddle it
    along its unit `axis` (PAIR_SPAN, PAIR_ANGLE, PAIR_OFF, PAIR_INNER; all in one segment's frame, at its scale);
    None where they do not."""
    v = x2 - x1
    span = float(np.linalg.norm(v))
    if not PAIR_SPAN[0] <= span <= PAIR_SPAN[1]:
        return None
    e = v / span
    if math.acos(min(1.0, abs(float(e @ axis)))) > PAIR_ANGLE:
        return None
    t = float((centre - x1) @ e) / span
    off = float(np.linalg.norm(centre - x1 - t * span * e))
    return off if PAIR_INNER <= t <= 1.0 - PAIR_INNER and off <= PAIR_OFF else None


def straddling_pairs(model: Model, base: np.ndarray, layout, rotations: list[np.ndarray], seen: np.ndarray,
                     centre_segment: np.ndarray, dofs=None) -> list[tuple[int, int, int, int]]:
    """(joint, marker, marker, DoF) of each calibrated knee, ankle and elbow hinge (ON_AXIS_JOINTS in its joint's
    or coordinate's name) whose parent carries two seen markers straddling its centre along its axis (PAIR_SPAN,
    PAIR_ANGLE, PAIR_OFF, PAIR_INNER) in the base parameters `base`; of several pairs, the one whose line passes
    nearest the centre.  `rotations`: each joint's URDF joint rotation (the hinge axis into its parent's frame);
    `seen`: (n_markers,) whether a trial shows each marker; `dofs`: the hinges' DoF indices to look at (default the
    calibrated axes', layout.axis_dofs)."""
    out = []
    for d in layout.axis_dofs if dofs is None else dofs:
        ji = model.joint_index(model.dofs[d].joint)
        j = model.joints[ji]
        if j.kind != "hinge" or not any(n in f"{j.name} {model.dofs[d].name}".lower() for n in ON_AXIS_JOINTS):
            continue
        s = float(base[layout.scale(centre_segment[ji])])
        a = rotations[ji] @ layout.axis_direction(base, d)
        c = s * base[layout.centre(ji)]
        mks = [k for k, mk in enumerate(model.markers) if mk.segment == j.parent and seen[k]]
        best = None
        for i, k in enumerate(mks):
            for m2 in mks[i + 1:]:
                off = straddle(c, a, s * base[layout.marker(k)], s * base[layout.marker(m2)])
                if off is not None and (best is None or off < best[0]):
                    best = (off, k, m2)
        if best is not None:
            out.append((ji, best[1], best[2], d))
    return out


#: m, at the base model's scale: a marker this close to a joint centre of its own segment is a point computed at
#: that centre (OpenSim's R_HJC at the femur's origin: 0 mm), not skin (20 mm or more from every centre in
#: models/human.urdf, gait2392 and Rajagopal).  Rajagopal's mid-epicondyle KneeJoint, 8 mm from its fitted knee
#: hinge, is near a centre, not at it: tied as well, it turned the left ankle 4 deg further from OpenSim's IK.
JOINT_MARKER_RADIUS = 0.005

#: The free segment scales needed for their priors to centre on the subject's size (their mean scale; Priors.size);
#: with fewer each is pulled towards the base model's.
SIZED_SEGMENTS = 3


#: m, at the base model's scale: markers of one segment the base model puts this close together are placeholders
#: (AddBiomechanics' models' thigh clusters: five markers at one point of the femur, 0 mm apart); the nearest
#: two distinct markers of models/human.urdf, gait2392 and Rajagopal2016 sit 10 mm or more apart.
PLACEHOLDER_RADIUS = 0.001


def placeholder_markers(model: Model, base: Parameters) -> tuple[int, ...]:
    """The markers (indices, in order) the base model puts within PLACEHOLDER_RADIUS of another marker of their
    segment: places to be filled by the data (OpenSim's marker placer moves them), not where the subject's are."""
    out = []
    for k, mk in enumerate(model.markers):
        s = float(base.scale[model.segment_index(mk.segment)])
        if any(j != k and mj.segment == mk.segment and s * float(np.linalg.norm(base.marker[j] - base.marker[k]))
               <= PLACEHOLDER_RADIUS for j, mj in enumerate(model.markers)):
            out.append(k)
    return tuple(out)


@dataclass(frozen=True)
class JointMarker:
    """A joint-centre marker (joint_centre_markers): marker `marker` (index) at joint `joint`'s centre, on the
    joint's parent segment (`on_parent`: its offset from the centre in that frame) or its child (its offset
    from the child segment's origin, where the joint is)."""

    marker: int
    joint: int
    on_parent: bool


def joint_centre_markers(model: Model, base: Parameters) -> tuple[JointMarker, ...]:
    """The markers the base model puts within JOINT_MARKER_RADIUS of a centre of a joint of their segment (as
    the joint's parent or its child; the nearest such joint), in marker order."""
    out = []
    for k, mk in enumerate(model.markers):
        s = float(base.scale[model.segment_index(mk.segment)])
        best: tuple[float, int, bool] | None = None
        for j, jt in enumerate(model.joints):
            for on_parent, seg, at in ((True, jt.parent, base.centre[j]), (False, jt.child, np.zeros(3))):
                if seg == mk.segment:
                    d = s * float(np.linalg.norm(base.marker[k] - at))
                    if d <= JOINT_MARKER_RADIUS and (best is None or d < best[0]):
                        best = (d, j, on_parent)
        if best is not None:
            out.append(JointMarker(k, best[1], best[2]))
    return tuple(out)


def held_layout(p: np.ndarray, base: np.ndarray, ce: np.ndarray, mk: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """What a held centre (ProblemOptions.hold_centres; entries `ce` of p) keeps against its parent's seen markers
    (entries `mk`, (n, 3)): their centroid in `p`, the base model's offset x0 of the centre from theirs, the base
    model's markers about their centroid b and sum(b * b), and kappa, the size of the markers' layout in `p` against
    the base model's (least squares).  The hold puts the centre at centroid + kappa * x0."""
    mid, mid0 = p[mk].mean(axis=0), base[mk].mean(axis=0)
    b = base[mk] - mid0
    bb = float(np.sum(b * b))
    return mid, base[ce] - mid0, b, bb, float(np.sum((p[mk] - mid) * b)) / bb


class PriorsMixin:
    """Problem's priors and limits (calibrate.problem.problem.Problem inherits it)."""

    def _prior_centres(self) -> tuple[np.ndarray, tuple, np.ndarray]:
        """The base model's parameter vector, its left/right pairs (symmetry_pairs) and the vector with
        the calibrated axes normalised (their priors' centres), kept while
        `base` is the same object (prior runs at every cost evaluation)."""
        cached = self.__dict__.get("_prior_cache")
        if cached is None or cached[0] is not self.base:
            base = self.base.vector()
            unit = base.copy()  # with the calibrated axes normalised: their priors' centres
            for d in self.axis_dofs:
                sl = self.layout.axis(d)
                unit[sl] = base[sl] / np.linalg.norm(base[sl])
            cached = (self.base, base, symmetry_pairs(self.model, base[self.layout.group("centre")].reshape(-1, 3)),
                      unit)
            self._prior_cache = cached
        return cached[1], cached[2], cached[3]

    def placeholders(self) -> tuple[int, ...]:
        """The base model's placeholder markers (placeholder_markers), kept while `base` is the same object."""
        cached = self.__dict__.get("_placeholder_cache")
        if cached is None or cached[0] is not self.base:
            cached = (self.base, placeholder_markers(self.model, self.base))
            self._placeholder_cache = cached
        return cached[1]

    def marker_sd(self) -> np.ndarray:
        """(n_markers,) each marker's prior SD (m): Priors.marker, Priors.placeholder for a placeholder; kept
        while the base and the settings are the same objects (read-only)."""
        cached = self.__dict__.get("_marker_sd_cache")
        if cached is None or cached[0] is not self.base or cached[1] is not self.settings:
            sd = np.full(len(self.model.markers), self.settings.priors.marker)
            sd[list(self.placeholders())] = self.settings.priors.placeholder
            sd.flags.writeable = False
            cached = (self.base, self.settings, sd)
            self._marker_sd_cache = cached
        return cached[2]

    def _block_index(self, group: str, seg_of: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A 3-vector group's pull towards the base model (_prior_terms' block): its entries in p (count, 3),
        and its Jacobian nonzeros' rows and columns (each entry's own, then its segment's scale), kept while the
        layout and `seg_of` (each block's segment) are the same objects."""
        cached = self.__dict__.setdefault("_block_index_cache", {}).get(group)
        if cached is None or cached[0] is not self.layout or cached[1] is not seg_of:
            L = self.layout
            idx = L.entries(group)
            rows = np.arange(idx.size)
            cached = (L, seg_of, (idx, np.concatenate([rows, rows]),
                                  np.concatenate([idx.ravel(), L.scale(np.repeat(seg_of, 3))])))
            self._block_index_cache[group] = cached
        return cached[2]

    def joint_markers(self) -> tuple[JointMarker, ...]:
        """The model's joint-centre markers (joint_centre_markers of the base model; none when
        priors.joint_marker is 0 or the markers are not free), kept while `base` is the same object."""
        if self.settings.priors.joint_marker <= 0 or "marker" not in self.settings.free:
            return ()
        cached = self.__dict__.get("_joint_marker_cache")
        if cached is None or cached[0] is not self.base:
            cached = (self.base, joint_centre_markers(self.model, self.base))
            self._joint_marker_cache = cached
        return cached[1]

    def _estimated(self, seg_pairs: list, joint_pairs: list) -> tuple[list, list]:
        """The left/right segment and joint pairs of which one at least is free (the priors on held blocks are
        constants) and neither side a segment no data reach (Settings.hold_segments; a centre's parent segment: held
        at the base model's while the fit runs, such a side would pull the other to the base model's size), kept while
        the layout is the same object."""
        cached = self.__dict__.get("_estimated_cache")
        if cached is None or cached[0] is not self.layout:
            L = self.layout
            blind = {self.model.segment_index(s) for s in self.settings.hold_segments}
            cs = self.centre_segment
            cached = (self.layout,
                      [(a, b) for a, b in seg_pairs if not (L.block("scale", a).held and L.block("scale", b).held)
                       and not {a, b} & blind],
                      [(a, b) for a, b in joint_pairs if not (L.block("centre", a).held and L.block("centre", b).held)
                       and not {int(cs[a]), int(cs[b])} & blind])
            self._estimated_cache = cached
        return cached[1], cached[2]

    def free_scales(self) -> np.ndarray:
        """The segments whose scale is free (not held), kept while the layout is the same object."""
        cached = self.__dict__.get("_free_scales_cache")
        if cached is None or cached[0] is not self.layout:
            cached = (self.layout, np.array([i for i in range(len(self.model.segments))
                                             if not self.layout.block("scale", i).held], dtype=int))
            self._free_scales_cache = cached
        return cached[1]

    def held_centres(self) -> list[tuple[int, list[int]]]:
        """(joint, its parent segment's seen markers) of each held centre (ProblemOptions.hold_centres) whose parent
        shows three or more markers, which place it; none when the centres are not free."""
        if "centre" not in self.settings.free or not self.settings.hold_centres:
            return []
        out = []
        for ji, j in enumerate(self.model.joints):
            if j.name in self.settings.hold_centres:
                mks = [k for k, mk in enumerate(self.model.markers) if mk.segment == j.parent and not self._unseen[k]]
                if len(mks) >= 3:
                    out.append((ji, mks))
        return out

    def _lateral_terms(self) -> list[tuple[int, int, int, float, float]]:
        """ProblemOptions.lateral_markers as (joint, marker, DoF index, distance, side): the side (+1 or -1)
        is the one of the base model's marker along its hinge axis, so that the distance is measured
        towards the lateral side whichever way the axis points.  Kept while `base` is the same object."""
        cached = self.__dict__.get("_lateral_cache")
        if cached is not None and cached[0] is self.base:
            return cached[1]
        m = self.model
        base = self.base.vector()
        joints = {j.name: i for i, j in enumerate(m.joints)}
        markers = {mk.name: i for i, mk in enumerate(m.markers)}
        out = []
        for jname, mname, dist in self.settings.lateral_markers:
            ji, mi = joints.get(jname), markers.get(mname)
            if ji is None or m.joints[ji].kind != "hinge":
                raise ValueError(f"lateral_markers: '{jname}' is not a hinge joint of the model")
            if mi is None or m.markers[mi].segment != m.joints[ji].parent:
                raise ValueError(f"lateral_markers: '{mname}' is not a marker of {m.joints[ji].parent}, the "
                                 f"segment {jname} hangs from")
            d, along = self._base_along(ji, mi, base)
            out.append((ji, mi, d, float(dist), 1.0 if along >= 0 else -1.0))
        self._lateral_cache = (self.base, out)
        return out

    def _base_along(self, ji: int, mi: int, base: np.ndarray) -> tuple[int, float]:
        """Hinge `ji`'s DoF index and marker `mi`'s offset from its centre along its axis in the base geometry
        `base` (full p, at scale 1): the sign says which side of the centre the base model puts the marker."""
        m, L = self.model, self.layout
        d = m.dof_index(m.joints[ji].dofs[0])
        a = self._urdf[m.joints[ji].urdf_joints[0]].rotation @ self.axis_direction(base, d)
        return d, float(a @ (base[L.marker(mi)] - base[L.centre(ji)]))

    def unslid_width_terms(self) -> list[tuple[int, int, int, float, float, float, float]]:
        """(joint, DoF, marker, side, target, per_scale, sd) for each hinge whose centre the slide cannot place
        (Problem.slid_hinges: its child segment held, nothing seen on or below it, as a locked ankle without foot
        markers) and whose Plug-in Gait lateral marker the trials show: its distance along the axis from the centre,
        the lab's measured one (ProblemOptions.lateral_markers, Priors.width) or, where none was measured, the base
        model's at the segment's scale (Priors.population_width; WIDTH_JOINTS: the knees, ankles and elbows), as a row
        of the solve's priors: nothing else places such a centre along its axis, and its prior alone left pig_walk-like
        sessions' ankles 16-57 mm from their measured widths (docs/benchmarks.md).  None where a pair of markers
        straddles the hinge (pair_terms, held_pair_terms), or the centres or markers are not free.  Kept while the
        settings, the seen markers and the base are the same."""
        cached = self.__dict__.get("_unslid_cache")
        key = (self.settings, self._unseen, self.base)
        if cached is not None and all(a is b for a, b in zip(cached[0], key, strict=True)):
            return cached[1]
        st, m, L = self.settings, self.model, self.layout
        out = []
        if {"centre", "marker"} <= set(st.free):
            still = set(st.hold_segments)
            skip = set(self._slides) | {ji for ji, *_ in self.pair_terms()} | {ji for ji, *_ in self.held_pair_terms()}

            def placeable(ji: int, mi: int) -> bool:
                j = m.joints[ji]
                return (ji not in skip and j.child in still and j.parent not in still and not self._unseen[mi]
                        and L.cols("centre", ji).size > 0 and L.cols("marker", mi).size > 0)

            measured = set()
            for ji, mi, d, dist, side in self._lateral_terms() if st.priors.width > 0 else []:
                measured.add(ji)
                if placeable(ji, mi):
                    out.append((ji, d, mi, side, float(dist), 0.0, st.priors.width))
            if st.priors.population_width > 0:
                base = self.base.vector()
                for name, marker in lateral_markers_of(m, WIDTH_JOINTS):
                    ji, mi = m.joint_index(name), m.marker_index(marker)
                    if ji not in measured and placeable(ji, mi):
                        d, along = self._base_along(ji, mi, base)
                        out.append((ji, d, mi, 1.0 if along >= 0 else -1.0, 0.0, abs(along),
                                    st.priors.population_width))
        self._unslid_cache = (key, out)
        return out

    def on_axis_terms(self) -> list[tuple[int, int, int]]:
        """(joint, marker, DoF index) of each hinge whose axis is held (Settings.hold_axes, or by auto-hold: the
        trials do not show it moving) and whose Plug-in Gait lateral marker rides on the segment it hangs from, seen
        in the trials (Priors.on_axis); none when priors.on_axis is 0 or axes, centres and markers are not all free
        (a lab that calibrates its markers alone keeps its model's geometry as it is)."""
        cached = self.__dict__.get("_on_axis_cache")  # kept while the settings and the seen markers are the same
        if cached is not None and cached[0] is self.settings and cached[1] is self._unseen:
            return cached[2]
        st, m = self.settings, self.model
        out = []
        if st.priors.on_axis > 0 and {"axis", "centre", "marker"} <= set(st.free):
            calibrated = set(self.layout.axis_dofs)
            pairs = on_axis_markers(m, lambda d: d not in calibrated)
            out = [(ji, mi, m.dof_index(m.joints[ji].dofs[0])) for ji, mi in pairs if not self._unseen[mi]]
        self._on_axis_cache = (self.settings, self._unseen, out)
        return out

    def pair_terms(self) -> list[tuple[int, int, int, int]]:
        """(joint, marker, marker, DoF) of each calibrated hinge whose parent carries a seen pair of markers
        straddling its centre along its axis (straddling_pairs, at the base geometry); none when priors.pair_axis
        is 0 or the markers are not free.  Kept while the base, the settings and the seen markers are the same."""
        cached = self.__dict__.get("_pair_cache")
        key = (self.base, self.settings, self._unseen)
        if cached is not None and all(a is b for a, b in zip(cached[0], key, strict=True)):
            return cached[1]
        out = []
        if self.settings.priors.pair_axis > 0 and "marker" in self.settings.free and self.layout.axis_dofs:
            out = straddling_pairs(self.model, self.base.vector(), self.layout, self._joint_rotations(), ~self._unseen,
                                   self.centre_segment)
        self._pair_cache = (key, out)
        return out

    def _joint_rotations(self) -> list[np.ndarray]:
        """Each joint's URDF joint rotation (its hinge axis into its parent's frame), as straddling_pairs takes them."""
        return [self._urdf[j.urdf_joints[0]].rotation if j.urdf_joints else np.eye(3) for j in self.model.joints]

    def held_pair_terms(self) -> list[tuple[int, int, int, int]]:
        """(joint, marker, marker, DoF) of each knee, ankle and elbow hinge whose axis is not calibrated (held: a still
        trial's, --hold-axes; or locked) and whose parent carries a seen pair of markers straddling its centre along
        its axis (straddling_pairs, at the base geometry): Priors.on_axis keeps its centre at their midpoint.  None
        when priors.on_axis is 0 or the centres and markers are not free.  Kept while the base, the settings and the
        seen markers are the same."""
        cached = self.__dict__.get("_held_pair_cache")
        key = (self.base, self.settings, self._unseen)
        if cached is not None and all(a is b for a, b in zip(cached[0], key, strict=True)):
            return cached[1]
        out = []
        st, m = self.settings, self.model
        if st.priors.on_axis > 0 and {"centre", "marker"} <= set(st.free):
            calibrated = set(self.layout.axis_dofs)
            held = [m.dof_index(j.dofs[0]) for j in m.joints if j.kind == "hinge"
                    and m.dof_index(j.dofs[0]) not in calibrated]
            out = straddling_pairs(m, self.base.vector(), self.layout, self._joint_rotations(), ~self._unseen,
                                   self.centre_segment, held)
        self._held_pair_cache = (key, out)
        return out

    def landmark_terms(self) -> list[tuple[int, int, dict[int, float], np.ndarray, float]]:
        """(joint, DoF, {marker: weight}, target, SD) of each knee and ankle hinge whose axis is calibrated
        (LANDMARK_JOINTS in its joint's or coordinate's name) with its anatomical landmarks seen: the midpoint of two
        markers straddling it (straddling_pairs: the epicondyles, the malleoli), else, for a knee, its Plug-in Gait
        lateral marker (LKNE over the lateral epicondyle, lateral_markers_of).  The prior keeps the centre's offset
        from that point across the axis at `target` (the parent's frame, scale 1): the base model's, of the landmark it
        puts nearest its axis (LANDMARK_OFF), with SD Priors.knee_landmark or Priors.ankle_landmark (0: no rows).  None
        when the centres and markers are not free.  Kept while the base, the settings and the seen markers are the
        same."""
        cached = self.__dict__.get("_landmark_cache")
        key = (self.base, self.settings, self._unseen)
        if cached is not None and all(a is b for a, b in zip(cached[0], key, strict=True)):
            return cached[1]
        st, m, L = self.settings, self.model, self.layout
        sds = dict(zip(LANDMARK_JOINTS, (st.priors.knee_landmark, st.priors.ankle_landmark), strict=True))
        out = []
        if any(sds.values()) and {"centre", "marker"} <= set(st.free):
            calibrated = set(L.axis_dofs)
            base = self.base.vector()

            def part(ji: int, d: int) -> str | None:
                """Which of LANDMARK_JOINTS the hinge is, by its joint's or coordinate's name."""
                name = f"{m.joints[ji].name} {m.dofs[d].name}".lower()
                return next((q for q in LANDMARK_JOINTS if q in name), None)

            def across(ji: int, d: int, mk: int) -> np.ndarray:
                """Marker mk's offset from the centre across the axis in the base geometry (scale 1)."""
                a = self._urdf[m.joints[ji].urdf_joints[0]].rotation @ self.axis_direction(base, d)
                y = base[L.centre(ji)] - base[L.marker(mk)]
                return y - a * float(a @ y)

            pairs = straddling_pairs(m, base, L, self._joint_rotations(), ~self._unseen, self.centre_segment)
            points = {ji: (d, {k1: 0.5, k2: 0.5}) for ji, k1, k2, d in pairs if part(ji, d) is not None}
            for jname, mk in lateral_markers_of(m, ("knee",)):
                ji, mi = m.joint_index(jname), m.marker_index(mk)
                d = m.dof_index(m.joints[ji].dofs[0])
                if ji not in points and d in calibrated and not self._unseen[mi]:
                    points[ji] = (d, {mi: 1.0})
            for ji, (d, w) in sorted(points.items()):
                # The landmark the base model puts nearest its axis: a marker the trials add has its start's place,
                # not the base model's; none within LANDMARK_OFF: the base model's axis passes by neither.
                t = min((across(ji, d, mk) for mk in w), key=lambda v: float(np.linalg.norm(v)))
                sd = sds[part(ji, d)]
                if sd > 0 and np.linalg.norm(t) <= LANDMARK_OFF:
                    out.append((ji, d, w, t, sd))
        self._landmark_cache = (key, out)
        return out

    def _pair_index(self, pairs: list[tuple[int, int, int, int]]) -> tuple[np.ndarray, ...]:
        """For pair_terms' `pairs` (P of them): each hinge's URDF joint rotation (P, 3, 3), the entries in p of its
        axis and of its two markers (P, 3 each), and the rows and columns of the pair rows' Jacobian nonzeros (the
        axis's 9, the second marker's 9 and the first's 9 of each pair, row-major), kept while `pairs` is the same."""
        cached = self.__dict__.get("_pair_index_cache")
        if cached is not None and cached[0] is pairs:
            return cached[1]
        m, L = self.model, self.layout
        ji, k1, k2, d = (np.array(c, dtype=int) for c in zip(*pairs, strict=True))
        R = np.array([self._urdf[m.joints[j].urdf_joints[0]].rotation for j in ji], dtype=float).reshape(-1, 3, 3)
        ax, m1, m2 = L.entries("axis", d), L.entries("marker", k1), L.entries("marker", k2)
        k = 3 * np.arange(len(pairs))[:, None] + np.repeat(np.arange(3), 3)[None]  # (P, 9) each pair's rows
        rows = np.concatenate([k, k, k], axis=1).ravel()
        cols = np.concatenate([np.tile(c, (1, 3)) for c in (ax, m2, m1)], axis=1)
        out = (R, ax, m1, m2, rows, cols.ravel())
        self._pair_index_cache = (pairs, out)
        return out

    def lateral_residuals(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The measured joint widths' residuals (calibrated - measured lateral distance) / priors.width and
        their Jacobian (n, n_free) at `p`; none when priors.width is 0."""
        sd = self.settings.priors.width
        terms = self._lateral_terms() if sd > 0 else []
        return self._along_axes(p, [(ji, d, {mi: 1.0}, side, dist) for ji, mi, d, dist, side in terms], sd)

    def pair_centre_residuals(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each straddled hinge's centre (pair_terms) along its axis from the midpoint of its two markers, at the
        segment's scale, / priors.width, and the Jacobian (n, n_free) at `p`: where along the axis the joint sits,
        which no motion shows (calibrate.problem.gauge.slide_centres), as a measured width fixes it from one
        lateral marker; none when priors.width is 0."""
        sd = self.settings.priors.width
        terms = self.pair_terms() if sd > 0 else []
        return self._along_axes(p, [(ji, d, {k1: 0.5, k2: 0.5}, -1.0, 0.0) for ji, k1, k2, d in terms], sd)

    def population_lateral_residuals(self, p: np.ndarray, joints: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
        """Where no width was measured, each hinge of `joints`: its Plug-in Gait lateral marker's distance along the
        axis from the centre against the base model's, both at the segment's scale, / priors.population_width, and
        the Jacobian (n, n_free) at `p`; none when population_width is 0."""
        sd = self.settings.priors.population_width
        return self._along_axes(p, self._population_terms(tuple(joints)) if sd > 0 else [], sd)

    def _population_terms(self, joints: tuple[str, ...]) -> list[tuple]:
        """_along_axes rows for population_lateral_residuals: (joint, DoF, {marker: 1}, side, 0, the base model's
        distance at scale 1), the side that of the base model's marker along its axis.  Kept while `base` and
        `joints` are the same."""
        cached = self.__dict__.get("_population_cache")
        if cached is not None and cached[0] is self.base and cached[1] == joints:
            return cached[2]
        m = self.model
        base = self.base.vector()
        lateral = dict(lateral_markers_of(m))
        out = []
        for name in joints:
            ji, mi = m.joint_index(name), m.marker_index(lateral[name])
            d, along = self._base_along(ji, mi, base)
            out.append((ji, d, {mi: 1.0}, 1.0 if along >= 0 else -1.0, 0.0, abs(along)))
        self._population_cache = (self.base, joints, out)
        return out

    def _along_axes(self, p: np.ndarray, rows: list[tuple], sd: float) -> tuple[np.ndarray, np.ndarray]:
        """Rows (side · s · a·(Σ w_k x_k − c) − target − s · per_scale) / sd and their Jacobian (n, n_free) at `p`: a
        point on a hinge's parent (its markers x_k weighted w_k, the weights summing to 1) along the hinge's axis a
        from its centre c, at the segment's scale s, one row per (joint, DoF, weights, side, target[, per_scale]):
        a target in metres, or (per_scale) one that grows with the segment's scale."""
        if not rows:
            return np.zeros(0), np.zeros((0, self.n_free))
        r, J = np.zeros(len(rows)), np.zeros((len(rows), self.np_full))
        for k, (ji, d, weights, side, target, *per) in enumerate(rows):
            r[k], cols, vals = self._along_axis_row(p, ji, d, weights, side, target, per[0] if per else 0.0, sd)
            np.add.at(J[k], cols, vals)
        return r, J @ self.tangent_map(p)

    def _hinge_axis_at(self, p: np.ndarray, ji: int, d: int) -> tuple[np.ndarray, slice, slice, np.ndarray, float,
                                                                     np.ndarray]:
        """Joint ji's hinge (DoF d) at full parameters `p`: its URDF joint rotation R, the entries of its axis and
        centre in p, the axis parameter's direction u and length, and the unit axis a = R u in the parent's frame
        (what the rows holding a centre or marker to the axis differentiate through)."""
        R = self._urdf[self.model.joints[ji].urdf_joints[0]].rotation
        ax, ce = self.layout.axis(d), self.layout.centre(ji)
        v = p[ax]
        nv = float(np.linalg.norm(v))
        u = v / nv
        return R, ax, ce, u, nv, R @ u

    def _along_axis_row(self, p: np.ndarray, ji: int, d: int, weights: dict[int, float], side: float, target: float,
                        per_scale: float, sd: float) -> tuple[float, np.ndarray, np.ndarray]:
        """One of _along_axes' rows: its residual and its nonzeros in the full parameters (columns: each marker's,
        the centre's, the scale's, the axis's; values)."""
        L = self.layout
        seg = self.centre_segment[ji]
        s = p[L.scale(seg)]
        R, ax, ce, u, nv, a = self._hinge_axis_at(p, ji, d)
        x = sum(w * p[L.marker(mk)] for mk, w in weights.items()) - p[ce]
        along = float(a @ x)
        cols = _cat(*(np.arange(L.marker(mk).start, L.marker(mk).stop) for mk in weights),
                    np.arange(ce.start, ce.stop), L.scale(seg), np.arange(ax.start, ax.stop))
        vals = _cat(*(side * s * w * a / sd for w in weights.values()), -(side * s * a / sd),
                    (side * along - per_scale) / sd, side * s * ((R.T @ x) @ (np.eye(3) - np.outer(u, u))) / nv / sd)
        return (side * s * along - target - s * per_scale) / sd, cols, vals

    def prior(self, p: np.ndarray, T: np.ndarray | None = None,
              jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Prior residuals and their Jacobian (n_prior, n_free) at full parameters `p`, through the
        free-parameter map `T` (default: tangent_map(p)); no Jacobian (None) if not `jacobian`."""
        r, nonzeros, pattern = self._prior_terms(p, T, jacobian)
        if nonzeros is None:
            return r, (np.zeros((0, self.n_free)) if jacobian else None)
        return r, pattern.dense(nonzeros[2], r.size, self.n_free)

    def prior_gram(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r, Jr, JrᵀJr): prior's residuals and Jacobian at `p`, and the Jacobian's Gram matrix (the
        priors' share of the normal equations) from its nonzeros (sparse_gram), not a dense product."""
        r, nonzeros, pattern = self._prior_terms(p, None, True)
        if nonzeros is None:
            return r, np.zeros((0, self.n_free)), np.zeros((self.n_free, self.n_free))
        return r, pattern.dense(nonzeros[2], r.size, self.n_free), pattern.gram(nonzeros[2], self.n_free)

    def _prior_terms(self, p: np.ndarray, T: np.ndarray | None, jacobian: bool) -> tuple[
            np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray] | None, _Pattern | None]:
        """The prior residuals and (with `jacobian`) their Jacobian through T as nonzeros (rows in
        order, columns, values; a position may repeat, its values then add up), None without rows, and
        those nonzeros' positions as a _Pattern (kept while they are the same: the priors' rows and columns
        do not change with p)."""
        st, m, L = self.settings, self.model, self.layout
        free = set(st.free)
        base, (seg_pairs, joint_pairs, mirror), unit = self._prior_centres()
        scale = p[L.scales]
        res: list[np.ndarray] = []
        # d residual / d p_full as (row, column, value) triplets: each row has one to four nonzeros,
        # and a dense (n_prior, n_full) product with T was most of a large model's prior time.
        trip: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

        def add(r: np.ndarray, nonzeros: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]) -> None:
            """Residuals `r`; with `jacobian`, their nonzeros (rows counted from r's first, columns, values)."""
            if jacobian:
                rows, cols, vals = nonzeros()
                trip.append((sum(x.size for x in res) + np.ravel(rows), np.ravel(cols), np.ravel(vals)))
            res.append(r)

        def block(group: str, seg_of: np.ndarray, sigma: float | np.ndarray) -> None:
            """Each entry's pull towards the base model's, at its segment's scale; `sigma` one SD or one per block."""
            idx, rows, cols = self._block_index(group, seg_of)  # idx (count, 3): full indices
            s = scale[seg_of][:, None]
            sd = np.broadcast_to(np.reshape(sigma, (-1, 1)), idx.shape)
            diff = p[idx] - base[idx]
            add((s * diff / sd).ravel(), lambda: (
                rows, cols, np.concatenate([np.broadcast_to(s / sd, idx.shape).ravel(), (diff / sd).ravel()])))

        if "marker" in free:
            block("marker", self.marker_segment, self.marker_sd())
        held = self.held_centres()
        if "centre" in free:
            # A held centre whose parent shows too few markers to place it against them: held in the frame itself.
            alone = set(st.hold_centres) - {m.joints[ji].name for ji, _ in held}
            sds = [st.priors.held_centre if j.name in alone else st.priors.centre for j in m.joints]
            block("centre", self.centre_segment, np.array(sds) if alone else st.priors.centre)
        if self.axis_dofs:
            idx = L.axis_entries.ravel()
            add((p[idx] - unit[idx]) / st.priors.axis, lambda: (
                np.arange(idx.size), idx, np.full(idx.size, 1.0 / st.priors.axis)))
        # A turning knee's or ankle's centre on the axis line through its landmarks (Priors.knee_landmark and
        # ankle_landmark; landmark_terms): s P(a) (c - x - t) / sd, x the pair's midpoint or the lateral marker, P the
        # projection across the axis a (3 rows of rank 2), t the base model's offset across its axis, all in the
        # parent's frame at its scale s.  The motion alone put real knees 13-37 mm distal of their epicondyles (the
        # thigh's skin markers slide with the knee's flexion) and ankles 8-43 mm from their malleoli (the foot's few
        # markers trade the ankle against the subtalar: docs/benchmarks.md).
        landmarks = self.landmark_terms()
        if landmarks:
            eye = np.eye(3)
            for ji, d, weights, t, sd in landmarks:
                seg = self.centre_segment[ji]
                R, ax, ce, u, nv, a = self._hinge_axis_at(p, ji, d)
                P = eye - np.outer(a, a)
                y = p[ce] - sum(w * p[L.marker(mk)] for mk, w in weights.items()) - t
                s = scale[seg]
                # d(P y)/d a = -((a.y) I + a y^T); d a / d v = R (I - u u^T) / |v|
                dv = -s / sd * ((a @ y) * eye + np.outer(a, y)) @ R @ (eye - np.outer(u, u)) / nv
                k = np.repeat(np.arange(3), 3)
                mcols = [np.tile(np.arange(L.marker(mk).start, L.marker(mk).stop), 3) for mk in weights]
                mvals = [(-w * s / sd * P).ravel() for w in weights.values()]
                add(s * (P @ y) / sd, lambda P=P, ce=ce, ax=ax, s=s, seg=seg, k=k, y=y, dv=dv, mcols=mcols,
                    mvals=mvals, sd=sd: (
                    _cat(k, *[k] * len(mcols), np.arange(3), k),
                    _cat(np.tile(np.arange(ce.start, ce.stop), 3), *mcols, np.full(3, L.scale(seg)),
                         np.tile(np.arange(ax.start, ax.stop), 3)),
                    _cat((s / sd) * P.ravel(), *mvals, (P @ y) / sd, dv.ravel())))
        seg_pairs, joint_pairs = self._estimated(seg_pairs, joint_pairs)
        if "scale" in free:
            # The free scales only: a held one (a segment no data reach, held at the subject's size) is not estimated.
            # Each segment's scale about the subject's size, its scales' mean relative to the base model's (SD
            # Priors.scale), and that size about the base model's (Priors.size): the base model's proportions at the
            # subject's size, so that a segment the trial barely sizes (a talus, an ulna, a hand with one marker)
            # follows the subject's size, not an adult base model's.  A hierarchical prior, s_k = S (1 + e_k) with
            # e_k ~ N(0, scale²) and S ~ N(1, size²), in whitened form: one row per segment, (s_k - b_k S̄) / scale,
            # and one for the size, (S̄ - 1) / sqrt(scale² / n + size²), S̄ the mean of s_k / b_k (its estimate);
            # with size 0 their squares add up to the independent priors' sum of ((s_k - b_k) / scale)².
            sd, k = st.priors.scale, self.free_scales()
            if k.size >= SIZED_SEGMENTS:
                b_k = base[L.scales][k]
                size = float(np.mean(scale[k] / b_k))
                n, col = k.size, L.scales.start + k
                tau = math.sqrt(sd ** 2 / n + st.priors.size ** 2)
                add(_cat((scale[k] - b_k * size) / sd, (size - 1.0) / tau), lambda: (
                    _cat(np.arange(n), np.repeat(np.arange(n), n), np.full(n, n)),
                    _cat(col, np.tile(col, n), col),
                    _cat(np.full(n, 1.0 / sd), (-np.outer(b_k, 1.0 / b_k) / (n * sd)).ravel(), 1.0 / (n * b_k * tau))))
            else:  # too few for a mean: each about the base model's
                add((scale[k] - base[L.scales][k]) / sd, lambda: (
                    np.arange(k.size), L.scales.start + k, np.full(k.size, 1.0 / sd)))
        # Left/right symmetry (Priors.symmetry_scale, symmetry_centre): a left segment's scale against
        # its right partner's, a left joint centre (at its parent's scale) against its right partner's
        # mirrored through the sagittal plane, both relative to the base model's own asymmetry.
        sd = st.priors.symmetry_scale
        # (a pair both held has nothing to estimate, one no data reach nothing to compare with: _estimated)
        if "scale" in free and sd > 0 and seg_pairs:
            a, b = np.array(seg_pairs).T
            k = np.arange(a.size)
            add(((scale[a] - scale[b]) - (base[L.scale(a)] - base[L.scale(b)])) / sd, lambda: (
                _cat(k, k), _cat(L.scale(a), L.scale(b)),
                _cat(np.full(a.size, 1.0 / sd), np.full(a.size, -1.0 / sd))))
        sd = st.priors.symmetry_centre
        if "centre" in free and sd > 0 and joint_pairs:
            jl, jr = np.array(joint_pairs, dtype=int).T
            sa, sb = self.centre_segment[jl], self.centre_segment[jr]
            il, ir = L.entries("centre", jl), L.entries("centre", jr)  # (pairs, 3)
            ka, kb = scale[sa][:, None], scale[sb][:, None]
            k = np.broadcast_to(np.arange(il.size).reshape(-1, 1, 3), (il.shape[0], 4, 3))  # pair by pair, as rows
            add(((ka * p[il] - mirror * (kb * p[ir]) - (base[il] - mirror * base[ir])) / sd).ravel(), lambda: (
                k, np.stack([il, ir, np.repeat(L.scale(sa)[:, None], 3, 1), np.repeat(L.scale(sb)[:, None], 3, 1)], 1),
                np.stack([np.repeat(ka / sd, 3, 1), -mirror * kb / sd, p[il] / sd, -mirror * p[ir] / sd], 1)))
        # A held centre (ProblemOptions.hold_centres) keeps its base-model offset from the centroid of its parent
        # segment's seen markers (Priors.held_centre): where the markers put the segment, as OpenSim's marker placer
        # puts its frame, the centre is the base model's; the data cannot tell a shift of the whole frame.  The
        # offset is taken at the size of those markers' own layout, as OpenSim's Scale measures a segment by its
        # markers' distances: kappa, their spread about their centroid against the base model's (least squares),
        # makes the row s (x - kappa x0) / sd, in the world the markers' offsets (s p_i) alone, the same at any
        # scale s of the segment.  At the segment's scale instead (s (x - x0)), that scale carried whatever pulled
        # the centre: gait2392's walk with --hold-centres back stretched its pelvis to 1.33-1.41 (docs/benchmarks.md).
        if held:
            sd = st.priors.held_centre
            for ji, mks in held:
                ce = L.entries("centre", np.array([ji]))[0]
                mk = L.entries("marker", np.array(mks))  # (n, 3)
                seg = self.centre_segment[ji]
                mid, x0, b, bb, kappa = held_layout(p, base, ce, mk)
                y = p[ce] - mid - kappa * x0
                s = scale[seg]
                n, k = len(mks), np.arange(3)
                # d y_k / d p_i,l = -(delta_kl / n + x0_k b_il / bb): the centroid's share and kappa's
                add(s * y / sd, lambda ce=ce, mk=mk, n=n, k=k, s=s, y=y, x0=x0, seg=seg, b=b, bb=bb: (
                    _cat(k, np.repeat(k, 3 * n), k),
                    _cat(ce, np.tile(mk.ravel(), 3), np.full(3, L.scale(seg))),
                    _cat(np.full(3, s / sd),
                          (-s / sd * (np.eye(3)[:, None, :] / n + x0[:, None, None] * b[None, :, :] / bb)).ravel(),
                          y / sd)))
        # A joint-centre marker keeps its base-model offset from its centre (Priors.joint_marker): on the joint's
        # parent, marker minus centre in that frame; on its child, the marker's offset from the child's origin.
        ties = self.joint_markers()
        if ties:
            sd = st.priors.joint_marker
            mk = L.entries("marker", np.array([t.marker for t in ties]))  # (n, 3)
            par = np.array([t.on_parent for t in ties])
            ce = L.entries("centre", np.array([t.joint for t in ties]))
            seg = self.marker_segment[[t.marker for t in ties]]
            x = p[mk] - np.where(par[:, None], p[ce], 0.0)
            x0 = base[mk] - np.where(par[:, None], base[ce], 0.0)
            s = scale[seg][:, None]
            k = np.arange(mk.size).reshape(-1, 3)
            add((s * (x - x0) / sd).ravel(), lambda: (
                _cat(k.ravel(), k[par].ravel(), k.ravel()),
                _cat(mk.ravel(), ce[par].ravel(), np.repeat(L.scale(seg), 3)),
                _cat(np.repeat(s.ravel() / sd, 3), np.repeat(-s[par].ravel() / sd, 3), ((x - x0) / sd).ravel())))
        # A held hinge's lateral marker on its axis line (Priors.on_axis): the part of its offset from the centre
        # across the axis, at the segment's scale, pulled to zero (3 rows of rank 2; the axis is not free here).
        on_axis = self.on_axis_terms()
        if on_axis:
            sd = st.priors.on_axis
            for ji, mi, d in on_axis:
                seg = self.centre_segment[ji]
                a = self._urdf[m.joints[ji].urdf_joints[0]].rotation @ self.axis_direction(p, d)
                P = np.eye(3) - np.outer(a, a)
                mk, ce = L.marker(mi), L.centre(ji)
                x = p[mk] - p[ce]
                s = scale[seg]
                k = np.repeat(np.arange(3), 3)
                add(s * (P @ x) / sd, lambda P=P, mk=mk, ce=ce, x=x, s=s, seg=seg, k=k: (
                    _cat(k, k, np.arange(3)),
                    _cat(np.tile(np.arange(mk.start, mk.stop), 3), np.tile(np.arange(ce.start, ce.stop), 3),
                          np.full(3, L.scale(seg))),
                    _cat((s / sd) * P.ravel(), -(s / sd) * P.ravel(), (P @ x) / sd)))
        # A held hinge's centre at the midpoint of the two markers straddling it (Priors.on_axis; held_pair_terms):
        # the epicondyles', the malleoli's, as the ISB and Plug-in Gait place a knee, ankle or elbow from them; no
        # motion places a held axis's centre, and left to its prior Rajagopal's static carried both knee centres 100 mm
        # from their epicondyles (docs/benchmarks.md).  s (c - (x1 + x2) / 2) / sd in the parent's frame, all three on
        # it at its scale s; along the axis it is where the slide puts the centre (slide_centres).
        held_pairs = self.held_pair_terms()
        if held_pairs:
            sd = st.priors.on_axis
            for ji, k1, k2, _ in held_pairs:
                seg = self.centre_segment[ji]
                ce, m1, m2 = L.centre(ji), L.marker(k1), L.marker(k2)
                x = p[ce] - 0.5 * (p[m1] + p[m2])
                s = scale[seg]
                k = np.arange(3)
                add(s * x / sd, lambda ce=ce, m1=m1, m2=m2, x=x, s=s, seg=seg, k=k: (
                    _cat(k, k, k, k),
                    _cat(np.arange(ce.start, ce.stop), np.arange(m1.start, m1.stop), np.arange(m2.start, m2.stop),
                         np.full(3, L.scale(seg))),
                    _cat(np.full(3, s / sd), np.full(3, -0.5 * s / sd), np.full(3, -0.5 * s / sd), x / sd)))
        # A hinge the slide cannot place (its child held) keeps its lateral marker at the measured width's distance
        # along the axis from its centre, or the population's (unslid_width_terms): one row each,
        # (side s a·(x - c) - target - s per_scale) / sd, a the axis in the parent's frame, s the parent's scale.
        for ji, d, mi, side, target, per, sd in self.unslid_width_terms():
            r, cols, vals = self._along_axis_row(p, ji, d, {mi: 1.0}, side, target, per, sd)
            add(np.array([r]), lambda cols=cols, vals=vals: (np.zeros(cols.size, dtype=int), cols, vals))
        # A hinge's axis along the line of the two markers straddling its centre (Priors.pair_axis; pair_terms):
        # (a x e) / sd, a the axis and e the pair's direction in the parent's frame (3 rows of rank 2, |a x e| the
        # sine of the angle between them, either way round).
        pairs = self.pair_terms()
        if pairs:
            # All pairs at once (Rajagopal's six hinges: a loop over them was a third of the priors' time).
            sd = st.priors.pair_axis
            R, ax, m1, m2, rows, cols = self._pair_index(pairs)
            v = p[ax]
            nv = np.array([np.linalg.norm(w) for w in v])  # (as the loop over pairs took them, to the bit)
            u = v / nv[:, None]
            a = np.array([Ri @ ui for Ri, ui in zip(R, u, strict=True)])
            x = p[m2] - p[m1]
            nx = np.array([np.linalg.norm(w) for w in x])
            e = x / nx[:, None]
            eye = np.eye(3)
            dv = -_cross_matrices(e) @ R @ (eye - u[:, :, None] * u[:, None, :]) / (nv * sd)[:, None, None]
            dx = _cross_matrices(a) @ (eye - e[:, :, None] * e[:, None, :]) / (nx * sd)[:, None, None]
            add((np.cross(a, e) / sd).ravel(), lambda: (
                rows, cols, np.concatenate([dv.reshape(-1, 9), dx.reshape(-1, 9), -dx.reshape(-1, 9)], axis=1).ravel()))
        if not res:
            return np.zeros(0), None, None
        if not jacobian:
            return np.concatenate(res), None, None
        r = np.concatenate(res)
        rows, cols, vals = (np.concatenate(x) for x in zip(*trip, strict=True))
        if T is not None:
            nonzeros = _sparse_product(rows, cols, vals, T, np.nonzero(T))
            return r, nonzeros, _Pattern(nonzeros[0], nonzeros[1])
        # Through the layout's tangent map, at the entries where it may be nonzero (a zero among them adds
        # nothing): which of J's nonzeros meets which of T's is the same at every p, so it is kept.
        product = self.__dict__.get("_prior_product")
        if product is None or not product.matches(rows, cols):
            product = _Product(rows, cols, L.tangent_nonzeros(), L.n_full)
            self._prior_product = product
        return r, product.apply(vals, L.tangent_values(p)), product.pattern

    def limits(self, Z: np.ndarray) -> np.ndarray:
        """Joint-limit residuals (F, n_dofs): LIMIT_WEIGHT/σ × how far each angle lies outside its
        range (zero inside it).  They never bias a pose within the range of motion; they keep a
        frame from sliding into a mirror-image branch or a full turn while the geometry is poor."""
        th = self.layout.frame.angles(Z)
        return self._limit_w * (th - np.clip(th, self.lower, self.upper))

    def limit_crossings(self, Z: np.ndarray,
                        dz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The joint limits a step dz (F, nz) from the poses Z (F, nz) carries an angle across (within its
        range at Z, more than one noise SD's worth of residual beyond it after the step): (frames, DoFs,
        weights w, residuals), each residual the limit's w·(θ − bound) continued to Z, inside the range.  A
        step's Gauss–Newton model has no limit row for an angle inside its range, so a step that takes one
        far past its limit (an angle the markers barely fix) is judged on a cost its model never saw; taken
        into the model, these rows keep such a step at the limit.  None if no limit is crossed."""
        th = self.layout.frame.angles(Z)
        after = th + self.layout.frame.angles(dz)
        w = self._limit_w
        inside = (th >= self.lower) & (th <= self.upper) & (w > 0) & ~self.locked
        # (A step that only grazes a limit, w·overshoot ≤ 1, is judged well enough on the model without it.)
        up, down = inside & (w * (after - self.upper) > 1.0), inside & (w * (self.lower - after) > 1.0)
        if not (up.any() or down.any()):
            return None
        f, d = np.nonzero(up | down)
        bound = np.where(up[f, d], self.upper[d], self.lower[d])
        return f, d, w[d], w[d] * (th[f, d] - bound)

    def _limit_active(self, lim: np.ndarray) -> np.ndarray:
        """(F, n_dofs) where a limit residual has a Jacobian row: outside a limit, or locked."""
        return (lim != 0) | self.locked


def _cat(*parts: np.ndarray | float) -> np.ndarray:
    """The 1-D arrays and scalars `parts` end to end (np.r_'s result for them, at a fraction of its time)."""
    return np.concatenate([np.atleast_1d(x) for x in parts])


def _cross_matrices(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3): [v]x of each row of `v` (n, 3)."""
    out = np.zeros((v.shape[0], 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return out


def _sparse_product(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, T: np.ndarray,
                    t_nonzeros: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nonzeros of J @ T (rows in order, columns, values; a position may repeat) for the matrix J
    given by its nonzeros (rows, cols, vals; repeated entries add up) and a T with few nonzeros per row
    (the tangent map: an identity but for each hinge axis's 3 × 2 block) at `t_nonzeros` (its rows in
    order, columns; a superset does too): every product of a nonzero of J with one of T's row."""
    return _Product(rows, cols, t_nonzeros, T.shape[0]).apply(vals, T[t_nonzeros])


class _Product:
    """_sparse_product's work for fixed J nonzero positions (rows, cols) and T nonzero positions `t_nonzeros`
    (T with `n_rows` rows): the order it sorts J's nonzeros in and which of T's each meets, found once;
    apply(vals, t_values) then gives _sparse_product's nonzeros, the same numbers, for J's values `vals` and
    T's values at `t_nonzeros`."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, t_nonzeros: tuple[np.ndarray, np.ndarray], n_rows: int):
        self.rows, self.cols = rows, cols
        order = np.lexsort((cols, rows))  # each sum in one order, whatever order the triplets came in
        r, c = rows[order], cols[order]
        t_rows, t_cols = t_nonzeros
        counts = np.bincount(t_rows, minlength=n_rows)
        first = np.cumsum(counts) - counts  # where each row of T starts among its nonzeros
        n = counts[c]
        self.order, self.n = order, n
        self.at = np.repeat(first[c] - np.cumsum(n) + n, n) + np.arange(int(n.sum()))  # T's nonzeros, row by row
        self.pattern = _Pattern(np.repeat(r, n), t_cols[self.at])

    def matches(self, rows: np.ndarray, cols: np.ndarray) -> bool:
        return rows.size == self.rows.size and np.array_equal(rows, self.rows) and np.array_equal(cols, self.cols)

    def apply(self, vals: np.ndarray, t_values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.pattern.rows, self.pattern.cols, np.repeat(vals[self.order], self.n) * t_values[self.at]


class _Pattern:
    """Nonzero positions (rows in order, cols; a position may repeat) of a matrix, and what _dense and sparse_gram
    find from them alone, made on first use: dense(vals, ...) and gram(vals, n) are _dense's and sparse_gram's
    results for the values `vals` at these positions."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray):
        self.rows, self.cols = rows, cols
        self._gram: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None

    def dense(self, vals: np.ndarray, n_rows: int, n: int) -> np.ndarray:
        return _dense(self.rows, self.cols, vals, (n_rows, n))

    def gram(self, vals: np.ndarray, n: int) -> np.ndarray:
        if self._gram is None or self._gram[0] != n:
            # each nonzero with every nonzero of its row (itself included), row by row
            rows = self.rows
            counts = np.bincount(rows)
            first = np.cumsum(counts) - counts
            k = counts[rows]
            me = np.repeat(np.arange(rows.size), k)
            partner = np.repeat(first[rows], k) + np.arange(me.size) - np.repeat(np.cumsum(k) - k, k)
            self._gram = (n, me, partner, self.cols[me] * n + self.cols[partner])
        _, me, partner, flat = self._gram
        out = np.zeros((n, n))
        np.add.at(out.reshape(-1), flat, vals[me] * vals[partner])
        return out


def _dense(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The matrix of `shape` with the nonzeros (rows, cols, vals), repeated positions summed in order
    (np.add.at: as np.bincount sums, at a hundredth of its time on an output of 10⁵ entries)."""
    out = np.zeros(shape)
    np.add.at(out.reshape(-1), rows * shape[1] + cols, vals)
    return out


def sparse_gram(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, n: int) -> np.ndarray:
    """JᵀJ (n, n) of the matrix J with the nonzeros (rows in order, cols, vals; repeated positions add
    up) and n columns: the products of each row's nonzeros summed into place, not a dense product
    (Rajagopal's 542 prior rows × 287 parameters with 637 nonzeros)."""
    return _Pattern(rows, cols).gram(vals, n)
