"""The start of the global solve: frame-wise poses for a geometry, the candidate start whose basin fits
best, the subsample of frames, and poses carried from the subsample to every frame."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace

import numpy as np

from ..model.blocks import FrameLayout
from ..model.kinematics import IDENTITY, Kinematics
from ..model.model import Parameters
from ..model.rotations import quat_inverse, quat_multiply, slerp_quats
from ..problem.options import SolverOptions
from ..problem.problem import Problem
from ..problem.state import State
from ..solve.ahead import idle_core, run_ahead
from ..solve.ik import FrameSolver
from ..solve.lm import Run

START_FRAMES = 60  # frames of the subsample on which choose_start solves each candidate start


START_ITERATIONS = 30  # ... for at most this many iterations


START_CHECK = 10  # after this many iterations each, a candidate far ahead of every other is taken ...
# ... far ahead: its cost below this fraction of every other candidate's.  Since a step sees the joint limits it
# crosses (calibrate.solve.lm), each leg gets further in its first 10 iterations and the gap there is narrower
# than where the legs end (pig_walk: 0.82 after 10, 0.70 after 30, the same winner).
START_LEAD = 0.85


START_GOOD_FIT = 1.5  # a candidate whose chi-square per observed coordinate is below this is taken at once


STRIDE = 10  # key-frame spacing of the start (frames of the trial) ...
STRIDE_SECONDS = 0.2  # ... and never further apart in time than this (a trial read at a lower rate)


def key_stride(rate: float) -> int:
    """Key-frame spacing of the start (start_poses) for a trial sampled at `rate` Hz: STRIDE frames, or
    fewer where STRIDE frames span more than STRIDE_SECONDS.  Each key frame is warm-started from the
    last, and squats' arms sweep 120° in about a second: read at 17 Hz (every 6th frame of 100), ten frames
    apart the wrist left the last key frame's basin and the calibration ended with it 150 mm off."""
    if not (math.isfinite(rate) and rate > 0):
        return STRIDE
    return max(1, min(STRIDE, int(round(STRIDE_SECONDS * rate))))


COARSE_FRAMES = 120  # the geometry's basin is found on about this many evenly spaced frames first


# ---------------------------------------------------------------------- start
def start_poses(kin: Kinematics, observed: np.ndarray, params: Parameters, stride: int = STRIDE,
                evaluator: Callable | None = None, progress: Callable[[float], None] | None = None,
                local: bool = False) -> State:
    """Per-frame coordinates for fixed geometry: frame-wise IK on every `stride`-th frame (warm-started
    key frame to key frame, the first from a global search), interpolated in between (slerp for
    the root rotation).  Frames with fewer than 3 markers take the nearest key frame's pose.
    `evaluator`: a faster per-frame (markers, d markers/dz) at `params` (Problem.frame_evaluator);
    `progress(share of the key frames done)` after each key frame; `local`: the first key frame also from
    a local solve from the default pose, the better fit taken (FrameSolver.global_start)."""
    model = kin.model
    F = observed.shape[0]
    p = params.vector()
    solver = FrameSolver(kin, p, evaluator)
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
            z, q = solver.global_start(observed[f], seen[f], local=local)
            budget = 200
        else:
            budget = 30
        z, q, cost, _ = solver.solve(z, q, observed[f], idx, np.arange(model.nz), budget, 1e-8)
        fits.append(math.sqrt(cost / idx.size))
        Zk[i], Qk[i] = z, q
        if progress is not None:
            progress((i + 1) / keys.size)
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
            Q[:, s:s + 4] = slerp_quats(keys, Qk[:, s:s + 4], inside)
    Q = Q.reshape(F, -1, 4)
    Q = np.where(Q[..., 3:4] < 0, -Q, Q)
    Z[:, FrameLayout.rotation] = 0.0
    return State(Z, Q[:, 0].copy(), p.copy(), Q[:, 1:].copy())


def stack_states(states: Sequence[State]) -> State:
    B = None if any(s.B is None for s in states) else np.concatenate([s.B for s in states])
    return State(np.concatenate([s.Z for s in states]), np.concatenate([s.Q for s in states]), states[0].p.copy(), B)


def frames_of(state: State, idx) -> State:
    """`state` on some of its frames (an index array or a slice)."""
    return State(state.Z[idx], state.Q[idx], state.p, None if state.B is None else state.B[idx])


def with_frames(state: State, idx: np.ndarray, part: State) -> State:
    """`state` with the poses of frames `idx` replaced by those of `part` (a state of those frames)."""
    Z, Q = state.Z.copy(), state.Q.copy()
    Z[idx], Q[idx] = part.Z, part.Q
    B = None
    if state.B is not None:
        B = state.B.copy()
        B[idx] = part.B
    return State(Z, Q, state.p, B)


def absolute(kin: Kinematics, state: State, spans: Sequence[slice] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Every frame's URDF coordinates (Z with absolute joint angles, root quaternions Q) of a solver
    state of a problem with kinematics `kin`, the ball angles continuous within each trial of
    `spans` (Kinematics.absolute)."""
    spans = spans or [slice(0, state.Z.shape[0])]
    parts = [kin.absolute(state.Z[sl], state.Q[sl], None if state.B is None else state.B[sl])
             for sl in spans]
    return np.concatenate([z for z, _ in parts]), np.concatenate([q for _, q in parts])


def choose_start(problem: Problem, observed: np.ndarray, spans: Sequence[slice], candidates: Mapping[str, Parameters],
                 say: Callable[[str], None], options: SolverOptions | None = None,
                 ahead: bool = True, lengths: Sequence[float] | None = None) -> tuple[Parameters, str]:
    """The start whose basin fits best: each candidate geometry (e.g. the MTB seed and the base
    model) solved with its poses on the subsample of frames the global solve starts from (the
    markers the model knows; the problem's settings before any noise is learnt), and the one that
    ends at the lowest cost kept.  Real trials need this: the MTB seed is only as good as the
    joints' motion lets it be (a walking trial's elbows flex 10-15 deg), and an arm started a few
    per cent too long or short settles in a basin with its elbow tens of degrees off, which no
    later step leaves; the cost, the same objective on the same frames, tells the basins apart.
    The candidates race: each is solved for START_CHECK iterations first, and one whose cost is then
    below START_LEAD times every other's is taken (pig_walk: the base model's 1.03e5 against the
    seed's 1.54e5); otherwise each goes on, from where it stopped, to START_ITERATIONS in all.
    Every candidate after the first is solved on the other core meanwhile (calibrate.solve.ahead), unless
    `ahead` is false or no core is idle (calibrate.solve.ahead.idle_core: a guess would only take its time).
    `lengths`: what each trial counts as in frames (spread_frames).
    `options`: the solver's (default SolverOptions()).  Returns the chosen geometry and a note naming each
    candidate's cost."""
    names = list(candidates)
    if len(names) == 1:
        return candidates[names[0]], f"started from {names[0]}"
    seen = np.all(np.isfinite(observed), axis=2)
    coarse = spread_frames(seen, spans, START_FRAMES, lengths)
    weight = subsample_weight(coarse, spans, lengths)
    problems = {name: Problem(problem.model, observed[coarse], problem.settings, problem.kin,
                              problem.base).with_frame_weight(weight)
                for name in names}  # each its own: a paused run keeps its buffers (Problem.buffers) while another runs
    per_frame = problems[names[0]].seen.sum(axis=1)
    n_seen = 3 * max(float(per_frame.sum() if weight is None else weight @ per_frame), 1.0)  # coordinates, weighted

    def leg(name: str) -> Iterator[float]:
        """The candidate's cost after START_CHECK iterations, then after START_ITERATIONS in all."""
        params, mine = candidates[name], problems[name]
        state = start_poses(problem.kin, observed[coarse], params, stride=1,
                            evaluator=mine.frame_evaluator(params.vector()))
        run = Run(mine, replace(state, p=params.vector()), options, max_iterations=START_ITERATIONS)
        yield run.advance(START_CHECK).cost
        yield run.advance().cost

    def fits(name: str, first: bool = True) -> str | None:
        """The note taking `name` at once, if it fits the subsample to the stated noise (chi-square per
        coordinate near 1: clean data, nothing to gain from another start); `first`: in the first pass."""
        if 2.0 * costs[name] / n_seen > START_GOOD_FIT:
            return None
        return (f"started from {name}: solved on {coarse.size} frames it fits them to the stated noise "
                f"(cost {costs[name]:.4g}), so " + ("no other start was tried" if first else "it was taken"))

    # Every candidate after the first is solved ahead on the other core (calibrate.solve.ahead), if it is idle: the
    # same steps as here, in the same order of decisions; a candidate not needed is stopped.
    ahead = ahead and idle_core()
    legs = {name: run_ahead(leg(name)) if k and ahead else leg(name) for k, name in enumerate(names)}
    costs: dict[str, float] = {}
    try:
        for name in names:
            say(f"start: {name}, solved on {coarse.size} frames")
            costs[name] = next(legs[name])
            if note := fits(name):
                say("start: " + note)
                return candidates[name], note
        best = min(costs, key=costs.get)
        far_ahead = all(costs[best] < START_LEAD * c for n, c in costs.items() if n != best)
        for name in [] if far_ahead else names:
            costs[name] = next(legs[name])
            if note := fits(name, first=False):
                say("start: " + note)
                return candidates[name], note
    finally:
        for values in legs.values():
            values.close()
    best = min(costs, key=costs.get)
    raced = f" ({START_CHECK} iterations each: one far ahead)" if far_ahead else ""
    note = (f"started from {best}: of " + ", ".join(f"{n} (cost {c:.4g})" for n, c in costs.items())
            + f", solved on {coarse.size} frames{raced}, its basin fits best")
    say("start: " + note)
    return candidates[best], note


def bridge(state: State, redo: np.ndarray, hit: np.ndarray, spans: list[slice]) -> State:
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
                rot = slerp_quats(good, Q[sl.start + good], np.clip(bad, good[0], good[-1]))
                Q[sl.start + bad] = np.where(rot[:, 3:4] < 0, -rot, rot)
    B = None if state.B is None else np.stack(rots[1:], axis=1) if rots[1:] else state.B.copy()
    return State(Z, rots[0], state.p, B)


def spread_frames(seen: np.ndarray, spans: Sequence[slice], target: int,
                  lengths: Sequence[float] | None = None) -> np.ndarray:
    """About `target` frames (indices into all trials' frames) spread over the trials of `spans` by
    their length, evenly within each (coarse_frames; at least 2 per trial).  `lengths`: what each
    trial counts as in frames, if not its length (a static trial weighed as a few frames,
    Problem.frame_weight)."""
    lengths = [sl.stop - sl.start for sl in spans] if lengths is None else lengths
    total = sum(lengths)
    return np.concatenate([sl.start + coarse_frames(seen[sl], max(2, round(target * n / total)))
                           for sl, n in zip(spans, lengths, strict=True)])


def subsample_weight(frames: np.ndarray, spans: Sequence[slice], lengths: Sequence[float] | None) -> np.ndarray | None:
    """Frame weights of the subsample `frames` (spread_frames with `lengths`) for Problem.subset: a trial
    that counts as fewer frames than it has (a static trial) weighs so that it keeps its share of the cost
    against the others, whose frames weigh 1; None when `lengths` is None (every trial as long as it is)."""
    if lengths is None:
        return None
    full = [sl.stop - sl.start for sl in spans]
    count = [int(np.sum((frames >= sl.start) & (frames < sl.stop))) for sl in spans]
    whole = [k for k in range(len(spans)) if lengths[k] >= full[k]]
    per = sum(full[k] for k in whole) / max(sum(count[k] for k in whole), 1) if whole else 1.0
    return np.concatenate([np.full(count[k], 1.0 if k in whole else lengths[k] / max(count[k], 1) / per)
                           for k in range(len(spans))])


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
        unit = q_start / np.linalg.norm(q_start, axis=-1, keepdims=True)
        turn = quat_multiply(q_solved / np.linalg.norm(q_solved, axis=-1, keepdims=True), quat_inverse(unit[frames]))
        if frames.size == 1:
            turns = np.tile(turn[0], (F, 1))
        else:
            turns = slerp_quats(frames, turn, np.clip(every, frames[0], frames[-1]))
        q = quat_multiply(turns, unit)
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        return np.where(q[:, 3:4] < 0, -q, q)

    Q = carry(solved.Q, start.Q)
    B = None
    if solved.B is not None:
        nb = solved.B.shape[1]
        sb = start.B if start.B is not None else np.broadcast_to(IDENTITY, (F, nb, 4))
        B = np.zeros((F, 0, 4)) if nb == 0 else np.stack([carry(solved.B[:, i], sb[:, i]) for i in range(nb)], axis=1)
    Z[:, FrameLayout.rotation] = 0.0
    return State(Z, Q, solved.p.copy(), B)
