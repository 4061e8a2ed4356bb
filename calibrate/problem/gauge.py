"""Gauges of the calibration problem: what the markers cannot fix (a segment frame's turn about its
parent's joint, a hinge centre along its axis) found, held by constraints in the solve, and the
segment frames turned to where the priors or a neutral trial want them."""

from __future__ import annotations

import math

import numpy as np

from calibrate.problem.state import FrameTurn

from ..model.blocks import cross3, perpendicular_basis
from ..seed.geometry import kabsch_rotation


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
        out = []
        into = {j.child: j for j in m.joints}
        still = set(self.settings.hold_segments)  # their geometry cannot turn with a frame

        def held_below(name: str) -> bool:
            """A held or locked DoF (or a held segment) down the hinge and universal chains below `name`."""
            return any(any(d in locked for d in j.dofs) or j.child in still or held_below(j.child)
                       for j in m.joints if j.parent == name and j.kind in ("hinge", "universal"))

        for si, seg in enumerate(m.segments):
            if seg.name in still:  # (a held kid below a ball joint does not block: the ball's angles absorb the turn)
                continue
            has_mk = bool(np.any(self.marker_segment == si))
            kids = [j for j in m.joints if j.parent == seg.name]
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

    def align_frames(self, p: np.ndarray) -> tuple[np.ndarray, list[FrameTurn]]:
        """Turn each free segment frame (see gauge_constraints) to where the priors want it.

        Per segment (parents first), the rotation G (root: and shift t) that best carries the
        base model's markers, joint centres and child hinge axes onto the current ones (weighted
        by the prior SDs; about the hinge axis only for a hinge's child) is taken out of the
        contents: x ← Gᵀ(x − t), and carried through hinge and universal joints into the
        segments below (see _turn), so that the data are unchanged once each turned frame's
        coordinates follow (root pose, a hinge's angle; ball angles are re-solved by the caller).
        Returns the new p and (segment, kind, G, t) per segment."""
        m, L, pr = self.model, self.layout, self.settings.priors
        base = self.base.vector()
        out = p.copy()
        moves = []
        for si, kind in self._gauges:
            s = out[L.scale(si)]
            pts, pts0, wts = [], [], []
            for k in np.flatnonzero(self.marker_segment == si):
                if not self.seen[:, k].any():
                    continue
                sl = L.marker(k)
                pts.append(s * out[sl])
                pts0.append(s * base[sl])
                wts.append(1 / pr.marker**2)
            for ji in np.flatnonzero(self.centre_segment == si):
                sl = L.centre(ji)
                pts.append(s * out[sl])
                pts0.append(s * base[sl])
                wts.append(1 / pr.centre**2)
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
            if kind == "rigid" and n_pts:
                wp = w[:n_pts] / w[:n_pts].sum()
                t = wp @ X[:n_pts] - wp @ X0[:n_pts]
                Xc = X.copy()
                Xc[:n_pts] -= t
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
            self._turn(out, si, G, t)
            moves.append((si, kind, G, t))
        return out, moves

    def neutral_gauges(self) -> list[tuple[int, str]]:
        """The segment frames that a neutral trial may turn (neutral_frames): the gauges, held axes
        not blocking (a held axis keeps its direction against the markers, re-expressed)."""
        return self._find_gauges(through_held=True)

    def neutral_frames(self, p: np.ndarray, Z: np.ndarray,
                       segments: list[tuple[int, str]]) -> tuple[np.ndarray, list[FrameTurn]]:
        """Turn the frames of `segments` (from neutral_gauges; not the root) so that the
        coordinates of the frames Z (F, nz) — a trial in the model's neutral pose — are zero on average:
        below a ball joint, by the mean (chordal) rotation of the joint in those frames; below a
        hinge or universal joint, about its last axis by the mean angle.  The contents are turned
        as in align_frames; returns the new p and (segment, kind, G, 0) per segment."""
        from scipy.spatial.transform import Rotation

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
                    turn = np.eye(3) if u.dof < 0 else Rotation.from_rotvec(
                        np.outer(Z[:, fl.angle(u.dof)], self.axis_direction(out, u.dof))).as_matrix()
                    R = R @ u.rotation @ turn
                    R0 = R0 @ u.rotation
                mean = kabsch_rotation(R.sum(axis=0).T)[0]  # the chordal mean of the joint's rotations
                G = mean.T @ R0
            elif kind == "axis":
                d = m.dof_index(j.dofs[-1])
                G = Rotation.from_rotvec(-float(np.mean(Z[:, fl.angle(d)])) * self.axis_direction(out, d)).as_matrix()
            else:
                continue
            self._turn(out, si, G)
            moves.append((si, kind, G, np.zeros(3)))
        return out, moves

    def _turn(self, out: np.ndarray, si: int, G: np.ndarray, t: np.ndarray | None = None) -> None:
        """Express segment si's contents in its frame turned by G (and shifted by t): in place.

        Below a hinge or universal joint the child's frame then turns too, by Oᵀ G O for the
        joint's fixed origin rotation O, with the joint's axes turned back in their own frames
        (R(Kᵀa, θ) = Kᵀ R(a, θ) K), so its angles are unchanged: the turn is carried down the
        tree until a ball joint, whose angles absorb it."""
        m, L = self.model, self.layout
        shift = np.zeros(3) if t is None else t / out[L.scale(si)]
        # A marker no frame shows stays at its offset in the turned frame: nothing places it but its
        # prior, whose centre (the base model's offset) is in the segment's frame wherever that turns.
        for k in np.flatnonzero((self.marker_segment == si) & ~self.unseen):
            sl = L.marker(k)
            out[sl] = G.T @ (out[sl] - shift)
        for ji in np.flatnonzero(self.centre_segment == si):
            sl = L.centre(ji)
            out[sl] = G.T @ (out[sl] - shift)
            j = m.joints[ji]
            if j.kind not in ("hinge", "universal") or not self._carries:
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
            self._turn(out, m.segment_index(j.child), K)

    def gauge_constraints(self, p: np.ndarray, slides: bool = True) -> np.ndarray:
        """K (n_gauge, n_free): steps with K dp = 0 do not turn (or, for the root, shift) a
        segment's frame against its contents.  Each segment's frame may turn freely with its
        markers, joint centres and child axes turned back (the joint angles absorb it), so only
        the priors would hold that motion; it is a curved valley that slows Levenberg–Marquardt.
        Fixing it keeps each segment's frame oriented as in the start (the base model's
        orientation), which is what the priors choose to first order."""
        m, L = self.model, self.layout
        pr = self.settings.priors
        rows: list[np.ndarray] = []
        for si, kind in self._gauges:
            items: list[tuple[np.ndarray, np.ndarray, float, np.ndarray | None]] = []  # x, cols, weight, basis
            s = p[L.scale(si)]  # free positions are at the subject's scale (see tangent_map)
            for k in np.flatnonzero((self.marker_segment == si) & ~self.unseen):  # (unseen: held, see _turn)
                items.append((s * p[L.marker(k)], L.cols("marker", k), 1 / pr.marker**2, None))
            for ji in np.flatnonzero(self.centre_segment == si):
                items.append((s * p[L.centre(ji)], L.cols("centre", ji), 1 / pr.centre**2, None))
                for dname in m.joints[ji].dofs:
                    d = m.dof_index(dname)
                    if d in self.axis_dofs:
                        a = self.axis_direction(p, d)
                        items.append((a, L.axis_cols(d), 1 / pr.axis**2, perpendicular_basis(a)))
            if kind == "axis":
                j = next(j for j in m.joints if j.child == m.segments[si].name)
                omegas = [self.axis_direction(p, m.dof_index(j.dofs[-1]))]
            else:
                omegas = list(np.eye(3))
            for w in omegas:
                r = np.zeros(self.n_free)
                for x, cols, wt, B in items:
                    v = wt * cross3(w, x)
                    r[cols] += v if B is None else v @ B
                rows.append(r)
            if kind == "rigid":
                for c in range(3):
                    r = np.zeros(self.n_free)
                    for _, cols, wt, B in items:
                        if B is None:
                            r[cols[c]] += wt
                    rows.append(r)
        # A hinge centre can slide along its axis with the child's contents sliding back: hold
        # it where it starts (the base model's or the seed's point on the axis).
        for ji in self._slides if slides else []:
            j = m.joints[ji]
            d = m.dof_index(j.dofs[0])
            u = self._urdf[j.urdf_joints[0]]
            a = u.rotation @ self.axis_direction(p, d)
            r = np.zeros(self.n_free)
            r[L.cols("centre", ji)] = a
            rows.append(r)
        return np.array(rows, dtype=float).reshape(len(rows), self.n_free)
