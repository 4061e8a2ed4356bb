"""The multi-dimensional assignment problem by Lagrangian relaxation (seed 002, Section 2; Poore & Rijavec).

A problem has D dimensions (markers, detections of camera 1, ..., of camera M) and a sparse list of
candidate *hyperedges* ``edges[h] = (i_0, ..., i_{D-1})`` with costs ``cost[h]``; -1 in a dimension is
its dummy (no marker / not seen by that camera).  Select hyperedges of least total cost such that every
real index of every dimension is used at most once (the paper's "summing all elements onto any one
dimension of χ is at most unity").  Leaving everything out costs 0, so useful hyperedges have negative cost.

Lagrangian relaxation: the uniqueness constraints of dimensions 2..D-1 are relaxed with multipliers
u_d ≥ 0 (cost c_h + Σ_d u_d[i_d]); what remains is a 2-D assignment between dimensions 0 and 1, solved
exactly (scipy's linear_sum_assignment) — its value minus Σ u is a lower bound (the *dual*).  A feasible
*primal* is recovered as the paper says: the pairs the dual fixed are merged into one dimension and the
next dimension is assigned to them by another 2-D assignment (multipliers of the dimensions still
relaxed kept), and so on to the last.  The multipliers follow a subgradient step (Polyak's rule towards
the best primal), and the best primal is kept; the gap primal − dual bounds its distance from the optimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

BIG = 1e9  # cost of a forbidden cell of a 2-D assignment


FREE = -1  # an edge whose fixed dimensions are all dummies so far


DROPPED = -2  # an edge inconsistent with the choices made so far


@dataclass(frozen=True)
class Assignment:
    """The best feasible selection found, with its cost and the bound."""

    chosen: np.ndarray  # indices of the selected hyperedges
    primal: float  # their total cost
    dual: float  # best lower bound on the optimum
    iterations: int  # subgradient iterations run

    @property
    def gap(self) -> float:
        """primal − dual ≥ 0; 0 proves the selection optimal."""
        return max(self.primal - self.dual, 0.0)


def _best(keys: np.ndarray, values: np.ndarray, n_keys: int) -> tuple[np.ndarray, np.ndarray]:
    """Per key 0..n_keys-1: the least value and the index of the edge that has it (-1: none)."""
    best = np.full(n_keys, np.inf)
    arg = np.full(n_keys, -1, dtype=np.int64)
    if keys.size:
        order = np.lexsort((values, keys))
        k = keys[order]
        first = np.ones(k.size, dtype=bool)
        first[1:] = k[1:] != k[:-1]
        best[k[first]] = values[order[first]]
        arg[k[first]] = order[first]
    return best, arg


def _stage(group: np.ndarray, n_groups: int, col: np.ndarray, n_cols: int, cost: np.ndarray):
    """One 2-D assignment of groups (fixed partial tuples; FREE edges belong to none) to the real indices of
    one dimension (`col`, -1 dummy).  Returns (new group of every edge, number of new groups, value,
    edges selected: the best edge of every chosen (group, index) cell)."""
    live = group != DROPPED
    g, c, v = group[live], col[live], cost[live]
    idx = np.flatnonzero(live)
    # cells: (group or free, index or dummy) -> key
    gk = np.where(g == FREE, n_groups, g)
    ck = np.where(c < 0, n_cols, c)
    best, arg = _best(gk * (n_cols + 1) + ck, v, (n_groups + 1) * (n_cols + 1))
    best = best.reshape(n_groups + 1, n_cols + 1)
    arg = arg.reshape(n_groups + 1, n_cols + 1)
    T, Q = n_groups, n_cols
    B = np.full((T + Q, Q + T), BIG)
    B[:T, :Q] = np.minimum(best[:T, :Q], BIG)
    keep = best[:T, Q]
    B[np.arange(T), Q + np.arange(T)] = np.minimum(keep, 0.0)  # a group with no index here, or dropped
    B[T + np.arange(Q), np.arange(Q)] = np.minimum(best[T, :Q], 0.0)  # an index starting a new group, or unused
    B[T:, Q:] = 0.0
    rows, cols = linear_sum_assignment(B)
    value = float(B[rows, cols].sum())
    new_of_cell = np.full((T + 1, Q + 1), DROPPED, dtype=np.int64)
    chosen = []
    n_new = 0
    for r, k in zip(rows, cols, strict=True):
        if r < T and k < Q:
            cell = (r, k)
        elif r < T:  # dummy column of group r
            if k != Q + r or keep[r] >= 0:
                continue
            cell = (r, Q)
        elif k < Q:
            if best[T, k] >= 0:
                continue
            cell = (T, k)
        else:
            continue
        if B[r, k] >= BIG:
            continue
        new_of_cell[cell] = n_new
        chosen.append(idx[arg[cell]])
        n_new += 1
    new_of_cell[T, Q] = FREE  # edges still dummy in every fixed dimension stay free
    new = np.full(group.shape, DROPPED, dtype=np.int64)
    new[idx] = new_of_cell[gk, ck]
    return new, n_new, value, np.array(chosen, dtype=np.int64)


def _recover(edges: np.ndarray, cost: np.ndarray, sizes, u: list[np.ndarray], first):
    """Primal recovery from the dual's first stage (`first`: its result); returns (selected edges, cost)."""
    D = edges.shape[1]
    group, n_groups, _, chosen = first
    for d in range(2, D):
        c = cost.copy()
        for e in range(d + 1, D):
            c += np.where(edges[:, e] >= 0, u[e][np.maximum(edges[:, e], 0)], 0.0)
        group, n_groups, _, chosen = _stage(group, n_groups, edges[:, d], sizes[d], c)
    return chosen, float(cost[chosen].sum()) if len(chosen) else 0.0


def solve_assignment(edges: np.ndarray, cost: np.ndarray, sizes, max_iterations: int = 30,
                     tolerance: float = 1e-6) -> Assignment:
    """Select hyperedges by Lagrangian relaxation (module docstring).  `edges` (H, D) int (-1 dummy),
    `cost` (H,), `sizes` the number of real indices of each dimension.  Stops when the gap is below
    `tolerance` × (1 + |primal|) or after `max_iterations` subgradient steps."""
    edges = np.asarray(edges, dtype=np.int64)
    cost = np.asarray(cost, dtype=float)
    D = edges.shape[1]
    if D < 2:
        raise ValueError("an assignment needs at least two dimensions")
    H = edges.shape[0]
    if H == 0:
        return Assignment(np.zeros(0, dtype=np.int64), 0.0, 0.0, 0)
    u = [np.zeros(int(s)) for s in sizes]
    best_chosen, best_primal, best_dual = np.zeros(0, dtype=np.int64), 0.0, -np.inf
    scale, stall = 1.0, 0
    g0 = edges[:, 0].copy()
    g0[g0 < 0] = FREE
    it = 0
    for it in range(1, max_iterations + 1):
        c = cost.copy()
        for e in range(2, D):
            c += np.where(edges[:, e] >= 0, u[e][np.maximum(edges[:, e], 0)], 0.0)
        first = _stage(g0, int(sizes[0]), edges[:, 1], int(sizes[1]), c)
        _, _, value, sel = first
        free = np.flatnonzero((first[0] == FREE) & (c < 0))  # dummy in dims 0 and 1: unconstrained there
        sel = np.concatenate([sel, free])
        dual = value + float(c[free].sum()) - sum(float(x.sum()) for x in u[2:])
        grads = [np.bincount(edges[sel, e][edges[sel, e] >= 0], minlength=int(sizes[e])) - 1.0 for e in range(D)]
        feasible = all(np.all(grads[e] <= 0) for e in range(2, D))
        if feasible:  # the dual selection is feasible: it is optimal
            primal = float(cost[sel].sum())
            chosen = sel
        else:
            chosen, primal = _recover(edges, cost, sizes, u, first)
        if dual > best_dual + 1e-12 * (1 + abs(dual)):
            best_dual, stall = dual, 0
        else:
            stall += 1
            if stall >= 3:
                scale, stall = scale / 2, 0
        if primal < best_primal or it == 1:
            best_primal, best_chosen = primal, chosen
        if feasible or best_primal - best_dual <= tolerance * (1 + abs(best_primal)):
            break
        # subgradient of the relaxed constraints (Σ usage − 1), projected onto u ≥ 0
        norm = sum(float(np.sum(np.where((u[e] > 0) | (grads[e] > 0), grads[e], 0.0) ** 2)) for e in range(2, D))
        if norm == 0:
            break
        step = scale * (best_primal - dual) / norm
        for e in range(2, D):
            u[e] = np.maximum(u[e] + step * grads[e], 0.0)
    best_dual = min(best_dual, best_primal)
    return Assignment(np.sort(best_chosen), best_primal, best_dual, it)


def exhaustive_assignment(edges: np.ndarray, cost: np.ndarray) -> tuple[np.ndarray, float]:
    """The optimum by depth-first search over every conflict-free selection (small problems only)."""
    edges = np.asarray(edges, dtype=np.int64)
    cost = np.asarray(cost, dtype=float)
    order = [int(h) for h in np.argsort(cost) if cost[h] < 0]  # a non-negative edge never helps
    best = [0.0, []]
    suffix = np.concatenate([np.cumsum(cost[order][::-1])[::-1], [0.0]]) if order else np.zeros(1)

    def dfs(pos: int, used: set, total: float, chosen: list) -> None:
        if total < best[0] - 1e-12:
            best[0], best[1] = total, list(chosen)
        if pos == len(order) or total + suffix[pos] >= best[0] - 1e-12:
            return
        h = order[pos]
        keys = {(d, int(i)) for d, i in enumerate(edges[h]) if i >= 0}
        if not keys & used:
            chosen.append(h)
            dfs(pos + 1, used | keys, total + cost[h], chosen)
            chosen.pop()
        dfs(pos + 1, used, total, chosen)

    dfs(0, set(), 0.0, [])
    return np.sort(np.array(best[1], dtype=np.int64)), float(best[0])


def is_feasible(edges: np.ndarray, chosen: np.ndarray) -> bool:
    """Whether no real index of any dimension is used twice by the chosen hyperedges."""
    sel = np.asarray(edges)[chosen]
    for d in range(sel.shape[1] if sel.ndim == 2 else 0):
        col = sel[:, d][sel[:, d] >= 0]
        if np.unique(col).size < col.size:
            return False
    return True
