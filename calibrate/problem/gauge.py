"""Gauges of the calibration problem: what the markers cannot fix (a segment frame's turn about its
parent's joint, a hinge centre along its axis) found, held by constraints in the solve, and the
segment frames turned to where the priors or a neutral trial want them."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from calibrate.problem.state import FrameTurn

from ..model.blocks import cross_rows, perpendicular_bases
from ..model.rotations import rotvec_matrices
from ..seed.geometry import kabsch_rotation

SLIDE_WITHOUT_MARKERS = True  # slide_centres places a hinge that a width places (measured, the population's, or a
# pair of markers straddling it) along its axis without the priors of the markers riding on its child

MARKER_FRAMES = 0.01  # a joint centre's weight, relative to its prior's, where the segment frames follow the markers
# (calibrate.calibration.gauge.align_markers): the centres only break ties (a segment with too few markers).


class GaugeMixin:
    """Problem's gauge handling (calibrate.problem.problem.Problem inherits it)."""

    def _find_gauges(self, through_held: bool = False) -> list[tuple[int, str]]:
        """Segments whose frame can turn (root: also shift) with no effect on the data, because
        everything expressed in it is free: (segment index, 'rigid' | 'rotation' | 'axis').
        `through_held`: a held axis may be re-expressed in a turned frame (its direction against
        the markers kept; Problem.neutral_gauges), else it blocks the turn as a locked DoF does."""
        m, free = self.model, set(self.settings.free)
        # A held axis is fixed in its parent's frame (and its child's), as a locked coordinate's is.
        locked = {name for name, _ in self.settings.lock} | (set() if through_held else set(self.settings.hold_axes))
        # A turn carried down the chains below (_turn) re-expresses the axes it passes: a neutral turn may pass a
        # locked coordinate's too (its angle, at the lock, unchanged; its axis's direction against the markers kept),
        # which --neutral needs under a locked subtalar (pig_walk's legs otherwise kept their static angles).
        carried = set() if through_held else locked
        out = []
        into = {j.child: j for j in m.joints}
        still = set(self.settings.hold_segments)  # their geometry cannot turn with a frame
        # ... though a neutral turn may carry through one, re-expressing the axis into it as a held axis's: such a
        # segment (a markerless hand or toes, held because no data reach it) otherwise kept every limb above it from
        # turning (Hamner2010's legs and arms under its blind toes and hands).
        blocking = set() if through_held else still

        def held_below(name: str) -> bool:
            """A held or locked DoF (`carried`; or a held segment) down the hinge, universal and weld chains below
            `name`."""
            return any(any(d in carried for d in j.dofs) or j.child in blocking or held_below(j.child)
                       for j in m.joints if j.parent == name and j.kind in ("hinge", "universal", "fixed"))

        def welded_group(name: str) -> list[str]:
            """`name` and the segments welded (fixed joints) below it, transitively."""
            return [name] + [n for j in m.joints if j.parent == name and j.kind == "fixed"
                             for n in welded_group(j.child)]

        for si, seg in enumerate(m.segments):
            if seg.name in still:  # (a held kid below a ball joint does not block: the ball's angles absorb the turn)
                continue
            # The segment and those welded below it turn as one (_turn carries a turn through a weld).
            group = welded_group(seg.name)
            has_mk = bool(np.any(np.isin(self.marker_segment, [m.segment_index(n) for n in group])))
            kids = [j for j in m.joints if j.parent in group]
            if (has_mk and "marker" not in free) or (kids and "centre" not in free):
                continue
            if any(j.kind in ("hinge", "universal") and "axis" not in free for j in kids):
                continue
            # A locked coordinate cannot absorb a turn of the frame below it, nor turn with a kid's axis.
            if seg.name in into and any(d in locked for d in into[seg.name].dofs):
                continue
            if held_below(seg.name):  # a kid's axis, or the turn carried down (_turn) into a held axis
                continue
            if si == 0:
                out.append((si, "rigid"))
            elif seg.name in into and into[seg.name].kind == "ball":
                out.append((si, "rotation"))
            elif seg.name in into and into[seg.name].kind in ("hinge", "universal") and "axis" in free:
                out.append((si, "axis"))
        return out

    def align_frames(self, p: np.ndarray, centre_weight: float = 1.0,
                     net: dict[int, np.ndarray] | None = None) -> tuple[np.ndarray, list[FrameTurn]]:
        """Turn each free segment frame (see gauge_constraints) to where the priors want it.

        Per segment (parents first), the rotation G (root: and shift t) that best carries the
        base model's markers, joint centres and child hinge axes onto the current ones (weighted
        by the prior SDs, the centres' times `centre_weight`: MARKER_FRAMES for the frames the
        markers define; about the hinge axis only for a hinge's child) is taken out of the
        contents: x ← Gᵀ(x − t), and carried through hinge and universal joints into the
        segments below (see _turn), so that the data are unchanged once each turned frame's
        coordinates follow (root pose, a hinge's angle; ball angles are re-solved by the caller).
        Returns the new p and (segment, kind, G, t) per segment; `net`, where given, gathers every
        segment's whole turn N (its frame R becomes R N), the turns carried down included (_turn)."""
        m, L, pr = self.model, self.layout, self.settings.priors
        base = self.base.vector()
        out = p.copy()
        moves = []
        marker_sd = self.marker_sd()
        for si, kind in self._gauges:
            s = out[L.scale(si)]
            pts, pts0, wts = [], [], []
            for k in np.flatnonzero(self.marker_segment == si):
                if not self.seen[:, k].any():
                    continue
                sl = L.marker(k)
                pts.append(s * out[sl])
                pts0.append(s * base[sl])
                wts.append(1 / marker_sd[k] ** 2)
            for ji in np.flatnonzero(self.centre_segment == si):
                sl = L.centre(ji)
                pts.append(s * out[sl])
                pts0.append(s * base[sl])
                wts.append(centre_weight / pr.centre**2)
            dirs, dirs0, dw = [], [], []
            for ji in np.flatnonzero(self.centre_segment == si):
                j = m.joints[ji]
                if j.kind in ("hinge", "universal"):  # the first axis, in this segment's frame
                    d = m.dof_index(j.dofs[0])
                    if d in self.axis_dofs:
                        u = self._urdf[j.urdf_joints[0]]
                        sl = L.axis(d)
                        dirs.append(u.rotation @ self.axis_direction(out, d))
                        dirs0.append(u.rotation @ (base[sl] / np.linalg.norm(base[sl])))
                        dw.append(1 / pr.axis**2)
            X = np.array(pts + dirs).reshape(-1, 3)
            X0 = np.array(pts0 + dirs0).reshape(-1, 3)
            w = np.array(wts + dw)
            n_pts = len(pts)
            t = np.zeros(3)
            c0 = np.zeros(3)
            if kind == "rigid" and n_pts:
                # G and t of min Σ w |G x0 + t - x|²: the points' weighted centroids c0 and c, G by Kabsch on the
                # points about them, t = c - G c0 (x0 ≈ Gᵀ(x - t))
                wp = w[:n_pts] / w[:n_pts].sum()
                c0, c = wp @ X0[:n_pts], wp @ X[:n_pts]
                X0 = X0.copy()
                X0[:n_pts] -= c0
                Xc = X.copy()
                Xc[:n_pts] -= c
            else:
                Xc = X
            if kind == "axis":
                j = next(j for j in m.joints if j.child == m.segments[si].name)
                a = self.axis_direction(out, m.dof_index(j.dofs[-1]))
                u0 = X0 - np.outer(X0 @ a, a)
                u1 = Xc - np.outer(Xc @ a, a)
                phi = math.atan2(float(np.sum(w * (np.cross(u0, u1) @ a))), float(np.sum(w * np.sum(u0 * u1, axis=1))))
                K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
                G = np.eye(3) + math.sin(phi) * K + (1 - math.cos(phi)) * K @ K
            else:
                if len(X) < 2:
                    continue
                G = kabsch_rotation((X0 * w[:, None]).T @ Xc)[0]  # G @ x0 ≈ x
                if kind == "rigid" and n_pts:
                    t = c - G @ c0
            self._turn(out, si, G, t, net)
            moves.append((si, kind, G, t))
        return out, moves

    def slid_hinges(self) -> list[int]:
        """The hinges slide_centres slides along their axes (joint indices): those whose centre is free, neither
        segment held, and whose child's markers are free or absent."""
        return list(self._slides)

    def slide_centres(self, p: np.ndarray, population: Sequence[str] = ()) -> np.ndarray:
        """Slide every hinge centre along its axis to where the anatomy's priors want it, the child segment's
        contents (its markers, the centres of the joints below it) slid back: the markers' places in
        the world and every joint angle are unchanged, so only the priors' cost changes.

        The data cannot see where along its axis a hinge sits; the solve holds each hinge centre's
        place along the axis where it started (gauge_constraints), but that place drifts as the axis
        turns in the solve or is held again at the base model's, and then reads as a shift of the
        centre (pig_walk: the left knee centre 40 mm along its flexion axis from the base model's place,
        the subtalar centres 36 mm).  The slides of all hinges are found together: the priors are linear in the free
        positions at fixed scales, so one least-squares solve over the slide lengths is exact.  Where the lab
        measured a joint's width (ProblemOptions.lateral_markers, priors.width), its lateral marker's distance
        from the centre along the axis joins the priors: the one place the measurement fixes what no marker shows;
        so does a hinge's place between two markers straddling it (the epicondyles: pair_centre_residuals), and, for
        the hinges named in `population` (knees, ankles, elbows whose width no one measured), the lateral marker's
        distance as the base model's at the segment's scale (Priors.population_width: population_lateral_residuals).

        Where a width places a hinge (any of the three), the priors of the markers riding on its child segment take
        no part (SLIDE_WITHOUT_MARKERS): the slide carries those markers with it, and where a lab strapped its shank
        wand or cluster, or how far out a malleolus marker stands, says nothing of where the knee lies along its axis;
        pulled by them, the knees of six Plug-in Gait sessions ended 16.9 mm RMS from their measured widths (all short)
        by the population's width, 11.2 without; with the widths used, 32 hinges 4.5 mm, 2.0 without
        (docs/benchmarks.md).  A hinge no width places keeps them: the child's markers and the
        parent's frame are then all that places it."""
        G, slid = self._slide_columns(p)
        if not slid:
            return p.copy()
        r, Jr = self.prior(p)
        rw, Jw = self.lateral_residuals(p)  # the lab's measured joint widths, where it gave them
        rm, Jm = self.pair_centre_residuals(p)  # a straddled hinge's centre at its two markers' midpoint
        rq, Jq = self.population_lateral_residuals(p, population)  # the population's widths, where none was measured
        widths = np.vstack([Jw, Jm, Jq])
        if SLIDE_WITHOUT_MARKERS:
            # A hinge that a width places (any of the three) is placed without its child's markers' priors: their
            # rows leave the slide's objective (the slide still carries those markers, as it must to move none).
            riders = self._riders(self._placed(G, slid, widths))
            if riders.size:
                keep = ~np.any(Jr[:, riders] != 0.0, axis=1)
                r, Jr = r[keep], Jr[keep]
        r, Jr = np.concatenate([r, rw, rm, rq]), np.vstack([Jr, widths])
        M = Jr @ G
        t = np.linalg.lstsq(M, -r, rcond=None)[0]
        return self.retract_parameters(p, G @ t)

    def width_placed(self, p: np.ndarray, population: Sequence[str] = ()) -> list[int]:
        """The hinges (joint indices) that a width places along their axes in slide_centres at `p`: a measured width,
        two markers straddling the hinge, or the population's width for the joints named in `population`; their
        child's markers' places along the axis follow the width, not those markers' priors (SLIDE_WITHOUT_MARKERS)."""
        if not SLIDE_WITHOUT_MARKERS:
            return []
        G, slid = self._slide_columns(p)
        if not slid:
            return []
        widths = np.vstack([self.lateral_residuals(p)[1], self.pair_centre_residuals(p)[1],
                            self.population_lateral_residuals(p, population)[1]])
        return self._placed(G, slid, widths)

    def _slide_columns(self, p: np.ndarray) -> tuple[np.ndarray, list[int]]:
        """Each slid hinge's slide direction in the free parameters (columns of G: its centre along the axis in
        the parent's frame, its child's markers and joint centres back along it in the child's), and the hinges."""
        m, L = self.model, self.layout
        cols, slid = [], []
        for ji in self._slides:
            j = m.joints[ji]
            d = m.dof_index(j.dofs[0])
            a = self.axis_direction(p, d)
            g = np.zeros(self.n_free)
            cc = L.cols("centre", ji)
            if cc.size == 0:
                continue
            g[cc] = self._urdf[j.urdf_joints[0]].rotation @ a  # the axis in the parent's frame
            child = m.segment_index(j.child)
            for k in np.flatnonzero(self.marker_segment == child):
                mc = L.cols("marker", k)
                if mc.size:
                    g[mc] = -a  # the axis in the child's frame (the hinge turns about it)
            for jk in np.flatnonzero(self.centre_segment == child):
                kc = L.cols("centre", jk)
                if kc.size:
                    g[kc] = -a
            cols.append(g)
            slid.append(ji)
        return (np.array(cols).T if cols else np.zeros((self.n_free, 0))), slid

    @staticmethod
    def _placed(G: np.ndarray, slid: list[int], widths: np.ndarray) -> list[int]:
        """The hinges of `slid` whose slide (G's columns) moves a width row (`widths`, their Jacobian)."""
        if not widths.size or not slid:
            return []
        seen = np.abs(widths @ G).max(axis=0)
        # (the ankle's width, which the knee's slide carries unchanged, reads 0 on the knee's column)
        return [ji for ji, s in zip(slid, seen, strict=True) if s > 1e-9 * seen.max()]

    def _riders(self, hinges: Sequence[int]) -> np.ndarray:
        """The free columns of the markers riding on the child segments of `hinges`."""
        m, L = self.model, self.layout
        cols = [L.cols("marker", k) for ji in hinges
                for k in np.flatnonzero(self.marker_segment == m.segment_index(m.joints[ji].child))]
        return np.concatenate(cols) if cols else np.zeros(0, dtype=int)

    def neutral_gauges(self) -> list[tuple[int, str]]:
        """The segment frames that a neutral trial may turn (neutral_frames): the gauges, held axes
        not blocking (a held axis keeps its direction against the markers, re-expressed)."""
        return self._find_gauges(through_held=True)

    def neutral_frames(self, p: np.ndarray, Z: np.ndarray, segments: list[tuple[int, str]],
                       net: dict[int, np.ndarray] | None = None,
                       targets: dict[int, float] | None = None) -> tuple[np.ndarray, list[FrameTurn]]:
        """Turn the frames of `segments` (from neutral_gauges; not the root) so that the
        coordinates of the frames Z (F, nz) — a trial in the model's neutral pose — are zero on average:
        below a ball joint, by the mean (chordal) rotation of the joint in those frames; below a
        hinge or universal joint, about its last axis by the mean angle.  `targets` (DoF index -> angle, rad):
        a static pose's values instead of zero for the DoFs it names; a ball joint's other angles then stay at
        their means in those frames (its mean rotation turned to the chain's at those angles).  The contents are
        turned as in align_frames; returns the new p and (segment, kind, G, 0) per segment; `net`, where given,
        gathers every segment's whole turn (as align_frames')."""
        m, fl = self.model, self.layout.frame
        out = p.copy()
        moves = []
        into = {j.child: j for j in m.joints}
        for si, kind in segments:
            j = into[m.segments[si].name]
            if kind == "rotation":
                R = np.broadcast_to(np.eye(3), (Z.shape[0], 3, 3))
                R0 = np.eye(3)
                for u in (self._urdf[n] for n in j.urdf_joints):
                    turn = np.eye(3) if u.dof < 0 else rotvec_matrices(
                        np.outer(Z[:, fl.angle(u.dof)], self.axis_direction(out, u.dof)))
                    R = R @ u.rotation @ turn
                    R0 = R0 @ u.rotation
                    if u.dof >= 0 and targets is not None:  # the pose's angle, else this DoF's mean there
                        aim = targets.get(u.dof, float(np.mean(Z[:, fl.angle(u.dof)])))
                        R0 = R0 @ rotvec_matrices(aim * self.axis_direction(out, u.dof))
                mean = kabsch_rotation(R.sum(axis=0).T)[0]  # the chordal mean of the joint's rotations
                G = mean.T @ R0
            elif kind == "axis":
                d = m.dof_index(j.dofs[-1])
                aim = (targets or {}).get(d, 0.0)
                G = rotvec_matrices(-(float(np.mean(Z[:, fl.angle(d)])) - aim) * self.axis_direction(out, d))
            else:
                continue
            self._turn(out, si, G, net=net)
            moves.append((si, kind, G, np.zeros(3)))
        return out, moves

    def _turn(self, out: np.ndarray, si: int, G: np.ndarray, t: np.ndarray | None = None,
              net: dict[int, np.ndarray] | None = None) -> None:
        """Express segment si's contents in its frame turned by G (and shifted by t): in place; each
        segment's whole turn composed into `net` where given (its frame R becomes R net[si]).

        Below a hinge, universal or fixed joint (a weld) the child's frame then turns too, by Oᵀ G O
        for the joint's fixed origin rotation O, with the joint's axes turned back in their own frames
        (R(Kᵀa, θ) = Kᵀ R(a, θ) K), so its angles are unchanged: the turn is carried down the
        tree until a ball joint, whose angles absorb it."""
        m, L = self.model, self.layout
        shift = np.zeros(3) if t is None else t / out[L.scale(si)]
        if net is not None:
            net[si] = net[si] @ G if si in net else G
        # A marker no frame shows stays at its offset in the turned frame: nothing places it but its
        # prior, whose centre (the base model's offset) is in the segment's frame wherever that turns.
        for k in np.flatnonzero((self.marker_segment == si) & ~self.unseen):
            sl = L.marker(k)
            out[sl] = G.T @ (out[sl] - shift)
        for ji in np.flatnonzero(self.centre_segment == si):
            sl = L.centre(ji)
            out[sl] = G.T @ (out[sl] - shift)
            j = m.joints[ji]
            # A welded child turns with its parent as a hinge's does (OpenSim's sacrum on its pelvis): left behind,
            # its contents moved with the turn and the re-solve after it could not repair the fit (Pose2Sim's
            # crouching child 8.21 mm, 2.57 with the weld turned; docs/benchmarks.md, "A weld turned").
            if not (j.kind == "fixed" or (j.kind in ("hinge", "universal") and self._carries)):
                continue
            K = G
            chain = [self._urdf[n] for n in j.urdf_joints]
            if any(np.any(u.xyz != 0) for u in chain[1:]):
                continue  # an offset inside the joint's chain would not turn with it
            for u in chain:
                K = u.rotation.T @ K @ u.rotation
                if u.dof >= 0:
                    sl = L.axis(u.dof)
                    out[sl] = K.T @ out[sl]
            self._turn(out, m.segment_index(j.child), K, net=net)

    def _gauge_plan(self) -> dict:
        """gauge_constraints' index arrays (they depend on the layout and the gauges, not on p): each
        constraint row's gauge, and each gauge's positions (markers, joint centres) and axes."""
        cached = self.__dict__.get("_gauge_plan_cache")
        if cached is not None and cached[0] is self.layout and cached[1] is self._gauges:
            return cached[2]
        m, L = self.model, self.layout
        pr = self.settings.priors
        axis_at = {d: i for i, d in enumerate(self.axis_dofs)}
        positions = []  # (gauge, entries in p, its segment's scale entry, free columns, weight)
        axes = []  # (gauge, index in axis_dofs, weight)
        rows = []  # (gauge, turn about e_row_axis (0-2), or -1: about the axis of DoF row_omega)
        rigid_rows = []
        marker_sd = self.marker_sd()
        for g, (si, kind) in enumerate(self._gauges):
            for k in np.flatnonzero((self.marker_segment == si) & ~self.unseen):  # (unseen: held, see _turn)
                sl = L.marker(k)
                positions.append((g, np.arange(sl.start, sl.stop), L.scale(si), L.cols("marker", k),
                                  1 / marker_sd[k] ** 2))
            for ji in np.flatnonzero(self.centre_segment == si):
                sl = L.centre(ji)
                positions.append((g, np.arange(sl.start, sl.stop), L.scale(si), L.cols("centre", ji), 1 / pr.centre**2))
                axes += [(g, axis_at[d], 1 / pr.axis**2) for d in map(m.dof_index, m.joints[ji].dofs) if d in axis_at]
            if kind == "axis":
                j = next(j for j in m.joints if j.child == m.segments[si].name)
                rows.append((g, -1, m.dof_index(j.dofs[-1])))
            else:
                rows += [(g, c, -1) for c in range(3)]
            if kind == "rigid":
                rigid_rows.append(g)
        pos_g, pos_idx, pos_scale, pos_cols, pos_w = (list(x) for x in zip(*positions, strict=True)) if positions \
            else ([], [], [], [], [])
        ax_g, ax_i, ax_w = (list(x) for x in zip(*axes, strict=True)) if axes else ([], [], [])
        row_g, row_axis, row_omega = (list(x) for x in zip(*rows, strict=True)) if rows else ([], [], [])
        pos_g, ax_g, row_g = np.array(pos_g, dtype=int), np.array(ax_g, dtype=int), np.array(row_g, dtype=int)
        # (row, position) and (row, axis) pairs of the same gauge
        pr_row, pr_pos = np.nonzero(row_g[:, None] == pos_g[None, :])
        ar_row, ar_ax = np.nonzero(row_g[:, None] == ax_g[None, :])
        plan = dict(n_rows=row_g.size, pos_idx=np.array(pos_idx, dtype=int).reshape(-1, 3),
                    pos_scale=np.array(pos_scale, dtype=int), pos_cols=np.array(pos_cols, dtype=int).reshape(-1, 3),
                    pos_w=np.array(pos_w), ax_i=np.array(ax_i, dtype=int), ax_w=np.array(ax_w),
                    row_omega=np.array(row_omega, dtype=int), row_axis=np.array(row_axis, dtype=int),
                    pr_row=pr_row, pr_pos=pr_pos, ar_row=ar_row, ar_ax=ar_ax,
                    rigid={g: np.flatnonzero(pos_g == g) for g in rigid_rows},
                    gauge_rows=[np.flatnonzero(row_g == g) for g in range(len(self._gauges))])
        self._gauge_plan_cache = (self.layout, self._gauges, plan)
        return plan

    def gauge_constraints(self, p: np.ndarray, slides: bool = True) -> np.ndarray:
        """K (n_gauge, n_free): steps with K dp = 0 do not turn (or, for the root, shift) a
        segment's frame against its contents.  Each segment's frame may turn freely with its
        markers, joint centres and child axes turned back (the joint angles absorb it), so only
        the priors would hold that motion; it is a curved valley that slows Levenberg–Marquardt.
        Fixing it keeps each segment's frame oriented as in the start (the base model's
        orientation), which is what the priors choose to first order."""
        m, L = self.model, self.layout
        plan = self._gauge_plan()
        n_rows = plan["n_rows"]
        K = np.zeros((n_rows, self.n_free))
        if n_rows:
            # each row's turn axis: a coordinate axis, or the hinge axis into an 'axis' gauge's segment
            W = np.zeros((n_rows, 3))
            fixed = plan["row_axis"] >= 0
            W[np.flatnonzero(fixed), plan["row_axis"][fixed]] = 1.0
            for r in np.flatnonzero(~fixed):
                W[r] = self.axis_direction(p, int(plan["row_omega"][r]))
            X = p[plan["pos_scale"]][:, None] * p[plan["pos_idx"]]  # free positions are at the subject's scale
            rr, pp = plan["pr_row"], plan["pr_pos"]
            K[rr[:, None], plan["pos_cols"][pp]] = plan["pos_w"][pp, None] * cross_rows(W[rr], X[pp])
            if plan["ax_i"].size:
                A = L.axis_directions(p)[plan["ax_i"]]
                B = perpendicular_bases(A)
                rr, aa = plan["ar_row"], plan["ar_ax"]
                v = plan["ax_w"][aa, None] * cross_rows(W[rr], A[aa])
                K[rr[:, None], L.axis_columns[plan["ax_i"][aa]]] = \
                    v[:, :1] * B[aa, 0] + v[:, 1:2] * B[aa, 1] + v[:, 2:] * B[aa, 2]
        rows = []
        for g, at in enumerate(plan["gauge_rows"]):  # each gauge's turns, then (the root) its shifts
            rows.append(K[at])
            items = plan["rigid"].get(g)
            if items is not None:  # the root's shift: its positions move with it
                r = np.zeros((3, self.n_free))
                for c in range(3):
                    r[c, plan["pos_cols"][items, c]] = plan["pos_w"][items]
                rows.append(r)
        # A hinge centre can slide along its axis with the child's contents sliding back: hold
        # it where it starts (the base model's or the seed's point on the axis).
        for ji in self._slides if slides else []:
            j = m.joints[ji]
            d = m.dof_index(j.dofs[0])
            u = self._urdf[j.urdf_joints[0]]
            a = u.rotation @ self.axis_direction(p, d)
            r = np.zeros((1, self.n_free))
            r[0, L.cols("centre", ji)] = a
            rows.append(r)
        return np.concatenate(rows) if rows else np.zeros((0, self.n_free))
