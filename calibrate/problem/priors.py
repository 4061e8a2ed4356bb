"""Priors of the calibration problem: the pull of every parameter towards the base model, left/right
symmetry, and the joint-limit residuals."""

from __future__ import annotations

import numpy as np

from ..model.model import Model


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


class PriorsMixin:
    """Problem's priors and limits (calibrate.problem.problem.Problem inherits it)."""

    def _prior_centres(self) -> tuple[np.ndarray, tuple]:
        """The base model's parameter vector and its left/right pairs (symmetry_pairs), kept while
        `base` is the same object (prior runs at every cost evaluation)."""
        cached = self.__dict__.get("_prior_cache")
        if cached is None or cached[0] is not self.base:
            base = self.base.vector()
            cached = (self.base, base, symmetry_pairs(self.model, base[self.layout.group("centre")].reshape(-1, 3)))
            self._prior_cache = cached
        return cached[1], cached[2]

    def prior(self, p: np.ndarray, T: np.ndarray | None = None,
              jacobian: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """Prior residuals and their Jacobian (n_prior, n_free) at full parameters `p`, through the
        free-parameter map `T` (default: tangent_map(p)); no Jacobian (None) if not `jacobian`."""
        st, m, L = self.settings, self.model, self.layout
        free = set(st.free)
        base, (seg_pairs, joint_pairs, mirror) = self._prior_centres()
        scale = p[L.scales]
        res: list[np.ndarray] = []
        jac: list[np.ndarray] = []  # d residual / d p_full

        def block(group: str, count: int, seg_of: np.ndarray, sigma: float) -> None:
            idx = L.entries(group)  # (count, 3) full indices
            s = scale[seg_of][:, None]
            diff = p[idx] - base[idx]
            res.append((s * diff / sigma).ravel())
            if not jacobian:
                return
            J = np.zeros((3 * count, self.np_full))
            rows = np.arange(3 * count)
            J[rows, idx.ravel()] = np.repeat(scale[seg_of], 3) / sigma
            J[rows, L.scale(np.repeat(seg_of, 3))] = diff.ravel() / sigma
            jac.append(J)

        if "marker" in free:
            block("marker", len(m.markers), self.marker_segment, st.priors.marker)
        if "centre" in free:
            block("centre", len(m.joints), self.centre_segment, st.priors.centre)
        for d in self.axis_dofs:
            sl = L.axis(d)
            res.append((p[sl] - base[sl] / np.linalg.norm(base[sl])) / st.priors.axis)
            if jacobian:
                J = np.zeros((3, self.np_full))
                J[:, sl] = np.eye(3) / st.priors.axis
                jac.append(J)
        if "scale" in free:
            ns = len(m.segments)
            res.append((scale - base[L.scales]) / st.priors.scale)
            if jacobian:
                J = np.zeros((ns, self.np_full))
                J[np.arange(ns), np.r_[L.scales]] = 1.0 / st.priors.scale
                jac.append(J)
        # Left/right symmetry (Priors.symmetry_scale, symmetry_centre): a left segment's scale against
        # its right partner's, a left joint centre (at its parent's scale) against its right partner's
        # mirrored through the sagittal plane, both relative to the base model's own asymmetry.
        sd = st.priors.symmetry_scale
        if "scale" in free and sd > 0 and seg_pairs:
            a, b = np.array(seg_pairs).T
            res.append(((scale[a] - scale[b]) - (base[L.scale(a)] - base[L.scale(b)])) / sd)
            if jacobian:
                J = np.zeros((a.size, self.np_full))
                J[np.arange(a.size), L.scale(a)] = 1.0 / sd
                J[np.arange(a.size), L.scale(b)] = -1.0 / sd
                jac.append(J)
        sd = st.priors.symmetry_centre
        if "centre" in free and sd > 0 and joint_pairs:
            for jl, jr in joint_pairs:
                sa, sb = int(self.centre_segment[jl]), int(self.centre_segment[jr])
                il, ir = L.entries("centre", [jl, jr])
                res.append((scale[sa] * p[il] - mirror * (scale[sb] * p[ir]) - (base[il] - mirror * base[ir])) / sd)
                if not jacobian:
                    continue
                J = np.zeros((3, self.np_full))
                J[np.arange(3), il] = scale[sa] / sd
                J[np.arange(3), ir] = -mirror * scale[sb] / sd
                J[:, L.scale(sa)] += p[il] / sd
                J[:, L.scale(sb)] -= mirror * p[ir] / sd
                jac.append(J)
        if not res:
            return np.zeros(0), np.zeros((0, self.n_free))
        if not jacobian:
            return np.concatenate(res), None
        T = self.tangent_map(p) if T is None else T
        return np.concatenate(res), np.vstack(jac) @ T

    def limits(self, Z: np.ndarray) -> np.ndarray:
        """Joint-limit residuals (F, n_dofs): LIMIT_WEIGHT/σ × how far each angle lies outside its
        range (zero inside it).  They never bias a pose within the range of motion; they keep a
        frame from sliding into a mirror-image branch or a full turn while the geometry is poor."""
        th = self.layout.frame.angles(Z)
        return self._limit_w * (th - np.clip(th, self.lower, self.upper))

    def _limit_active(self, lim: np.ndarray) -> np.ndarray:
        """(F, n_dofs) where a limit residual has a Jacobian row: outside a limit, or locked."""
        return (lim != 0) | self.locked
