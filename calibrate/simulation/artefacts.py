"""What a lab adds to the true marker positions: soft-tissue artefact, gaps (occlusions), swapped labels
and spikes (the corruptions, written beside a simulation so that a benchmark can score them)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.text import atomic_write_text
from ..model.kinematics import Kinematics
from ..model.model import Model, Parameters

# Soft-tissue artefact: amplitude of a segment's markers as a multiple of `sta_mm` (the shank's), each
# marker drawn in STA_SPREAD times it.  Published figures behind them: docs/simulation.md.
STA_FACTOR = {"femur": 2.0, "tibia": 1.0, "pelvis": 0.6, "torso": 0.6, "humerus": 1.5, "ulna": 0.8, "radius": 0.8,
              "hand": 0.3, "head": 0.3, "talus": 0.3, "calcn": 0.3}


STA_ACROMION = 2.5  # torso markers within 6 cm (scaled) of a shoulder centre ride on the scapula


STA_SPREAD = (0.5, 1.5)


SWAP_FRAMES = (3, 10)  # frames of one swapped-label episode


SWAP_DISTANCE = (0.05, 0.20)  # m: neutral-pose distance of the markers a swap may exchange


SPIKE_SIZE = (0.030, 0.100)  # m: single-frame gross errors


GAP_SECONDS = (0.05, 0.6)  # s: one occlusion, as `occlusions` draws them


@dataclass(frozen=True)
class Corruption:
    """One corrupted marker sample of a simulated trial: what outlier rejection should catch."""

    kind: str  # 'swap' (two labels exchanged) or 'spike' (a single-frame gross error)
    frame: int  # 0-based
    marker: str  # the label whose position is wrong in this frame
    partner: str  # the other label of a swap; '' for a spike
    error: float  # m: distance of the observed position from where the skin marker was


def occlusions(n_frames: int, n_markers: int, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Boolean (n_frames, n_markers) mask of occluded samples: short bursts, as cameras lose markers.

    Each marker loses on average 1.5 intervals of 0.05-0.6 s; at most 20 % of its frames.
    """
    mask = np.zeros((n_frames, n_markers), dtype=bool)
    for k in range(n_markers):
        for _ in range(rng.poisson(1.5 * n_frames / (10 * rate))):
            length = max(1, int(rng.uniform(0.05, 0.6) * rate))
            start = int(rng.integers(0, max(1, n_frames - length)))
            mask[start:start + length, k] = True
        if mask[:, k].mean() > 0.2:  # keep it realistic: trim to the first 20 %
            idx = np.flatnonzero(mask[:, k])
            mask[idx[int(0.2 * n_frames):], k] = False
    return mask


def soft_tissue_artefact(model: Model, angles: np.ndarray, sta_mm: float,
                         rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Displacement (n_frames, n_markers, 3) of every skin marker from its bone, in its segment's frame
    (m), and each marker's amplitude a (n_markers,) (m).

    d(t) = a · Σ_k w_k e_k sin(π/2 · θ_k(t) / θ_lim,k) over the DoFs k of the joints into and out of the
    marker's segment: θ_lim the DoF's larger limit, e_k a random direction around one per marker (the
    artefact mostly moves a marker one way), w_k (Σ = 1) shared by joints in proportion to
    1 / distance² from the marker (at least 5 cm) and equally by a joint's DoFs.  So |d| ≤ a, zero in
    the neutral pose, a smooth function of the joint angles (no noise); a = `sta_mm` × STA_FACTOR of the
    segment × a factor drawn in STA_SPREAD (torso markers by a shoulder: STA_ACROMION)."""
    n_frames = angles.shape[0]
    disp = np.zeros((n_frames, len(model.markers), 3))
    amp = np.zeros(len(model.markers))
    if sta_mm <= 0:
        return disp, amp
    lim = np.array([max(abs(d.lower), abs(d.upper)) if np.isfinite(d.lower) and np.isfinite(d.upper) else np.pi
                    for d in model.dofs])
    g = np.sin(0.5 * np.pi * np.clip(angles / lim, -1.0, 1.0))  # (F, n_dofs)
    size = float(np.linalg.norm(model.joints[model.joint_index("neck")].centre)) if "neck" in [
        j.name for j in model.joints] else 0.45  # torso length, for the acromion rule
    for m, mk in enumerate(model.markers):
        kind = "_".join(p for p in mk.segment.split("_") if p not in ("r", "l"))
        # joints into (centre at the segment origin) and out of (centre in this frame) the segment
        near = [(j, np.zeros(3)) for j in model.joints if j.child == mk.segment]
        near += [(j, np.asarray(j.centre)) for j in model.joints if j.parent == mk.segment]
        factor = STA_FACTOR.get(kind, 0.5)
        if kind == "torso" and any(j.name.startswith("shoulder") and np.linalg.norm(mk.offset - c) < 0.06 / 0.45 * size
                                   for j, c in near):
            factor = STA_ACROMION
        amp[m] = 1e-3 * sta_mm * factor * rng.uniform(*STA_SPREAD)
        main = rng.normal(size=3)
        main /= np.linalg.norm(main)
        near = [(j, c) for j, c in near if j.dofs]
        if not near:
            continue
        wj = np.array([1.0 / max(float(np.linalg.norm(mk.offset - c)), 0.05) ** 2 for _, c in near])
        wj /= wj.sum()
        for (j, _), w in zip(near, wj, strict=True):
            for dof in j.dofs:
                e = main + 0.5 * rng.normal(size=3)
                e /= np.linalg.norm(e)
                disp[:, m, :] += (amp[m] * w / len(j.dofs)) * g[:, model.dof_index(dof), None] * e
    return disp, amp


def occlusions_fraction(n_frames: int, n_markers: int, rate: float, fraction: float,
                        rng: np.random.Generator) -> np.ndarray:
    """Boolean (n_frames, n_markers) mask with `fraction` of the samples occluded (to within one gap), in
    gaps of GAP_SECONDS on random markers, none losing more than max(20 %, 3 × fraction) of its frames."""
    mask = np.zeros((n_frames, n_markers), dtype=bool)
    target = int(round(fraction * n_frames * n_markers))
    cap = max(0.2, 3.0 * fraction) * n_frames
    tries = 0
    while mask.sum() < target and tries < 100000:
        tries += 1
        k = int(rng.integers(n_markers))
        length = min(n_frames, max(1, int(rng.uniform(*GAP_SECONDS) * rate)))
        start = int(rng.integers(0, n_frames - length + 1))
        new = mask[:, k].copy()
        new[start:start + length] = True
        if new.sum() <= cap:
            mask[:, k] = new
    return mask


def swap_pairs(model: Model, neutral: np.ndarray) -> list[tuple[int, int]]:
    """Marker pairs a labeller may exchange: on the same or adjacent segments with neutral-pose distance
    in SWAP_DISTANCE, or the left and right marker of one landmark on the pelvis, torso or head."""
    seg = [mk.segment for mk in model.markers]
    adjacent = {(j.parent, j.child) for j in model.joints} | {(j.child, j.parent) for j in model.joints}
    names = model.marker_names
    pairs = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            dist = float(np.linalg.norm(neutral[i] - neutral[j]))
            near = (seg[i] == seg[j] or (seg[i], seg[j]) in adjacent) and SWAP_DISTANCE[0] <= dist <= SWAP_DISTANCE[1]
            mirror = (seg[i] == seg[j] and seg[i] in ("pelvis", "torso", "head") and len(names[i]) > 1
                      and {names[i][0], names[j][0]} == {"R", "L"} and names[i][1:] == names[j][1:])
            if near or mirror:
                pairs.append((i, j))
    return pairs


def corrupt(model: Model, observed: np.ndarray, skin: np.ndarray, neutral: np.ndarray, swaps: int, spikes: int,
             rng: np.random.Generator) -> tuple[Corruption, ...]:
    """Exchange labels in `swaps` episodes of SWAP_FRAMES frames and add `spikes` single-frame errors of
    SPIKE_SIZE to `observed` (in place), on visible samples, no sample twice; the corrupted samples."""
    n_frames = observed.shape[0]
    names = model.marker_names
    used = np.isnan(observed[..., 0])  # gaps and corrupted samples are off limits
    out: list[Corruption] = []
    pairs = swap_pairs(model, neutral) if swaps else []
    if swaps and not pairs:
        raise ValueError("swaps: the model has no marker pairs close enough to swap; ask for none")
    for _ in range(int(swaps)):
        for _attempt in range(1000):
            i, j = pairs[int(rng.integers(len(pairs)))]
            length = int(rng.integers(SWAP_FRAMES[0], SWAP_FRAMES[1] + 1))
            if length > n_frames:
                continue
            f0 = int(rng.integers(0, n_frames - length + 1))
            fr = slice(f0, f0 + length)
            dist = np.linalg.norm(skin[fr, i] - skin[fr, j], axis=1)
            if not used[fr, i].any() and not used[fr, j].any() and dist.min() >= SWAP_DISTANCE[0] * 0.6:
                break
        else:
            raise ValueError(f"swaps: cannot place {swaps} swap episodes of {SWAP_FRAMES[0]}-{SWAP_FRAMES[1]} frames "
                             f"on visible samples of a {n_frames}-frame trial; ask for fewer or a longer trial")
        observed[fr, i], observed[fr, j] = observed[fr, j].copy(), observed[fr, i].copy()
        used[fr, i] = used[fr, j] = True
        for f, dd in zip(range(f0, f0 + length), dist, strict=True):
            out += [Corruption("swap", f, names[i], names[j], float(dd)),
                    Corruption("swap", f, names[j], names[i], float(dd))]
    free = np.argwhere(~used)
    if spikes > len(free):
        raise ValueError(f"spikes: {spikes} asked for but only {len(free)} visible samples are left; ask for fewer")
    picks = free[rng.choice(len(free), size=int(spikes), replace=False)] if spikes else np.zeros((0, 2), int)
    for f, k in picks:
        size = float(rng.uniform(*SPIKE_SIZE))
        v = rng.normal(size=3)
        observed[f, k] += size * v / np.linalg.norm(v)
        out.append(Corruption("spike", int(f), names[k], "", size))
    return tuple(sorted(out, key=lambda c: (c.frame, names.index(c.marker))))


def skin_markers(kin: Kinematics, Z: np.ndarray, quat: np.ndarray, truth: Parameters,
                  offsets: np.ndarray) -> np.ndarray:
    """Markers (F, M, 3) with per-frame marker offsets (F, M, 3; unscaled, segment frames)."""
    nf, nm = offsets.shape[:2]
    P = np.tile(truth.vector()[:, None], (1, nf))
    P[kin.model.layout.group("marker"), :] = offsets.reshape(nf, 3 * nm).T
    M, _ = kin.h.map(nf, "thread", 2)(Z.T, quat.T, P)
    return np.asarray(M).reshape(3, nf, nm).transpose(1, 2, 0)


CORRUPTION_COLUMNS = ("kind", "frame", "marker", "partner", "error_mm")


def write_corruptions(path: str | os.PathLike[str], corruptions: tuple[Corruption, ...]) -> None:
    """CSV of the corrupted marker samples: kind (swap/spike), frame (0-based row of the trial),
    marker (the label whose position is wrong), partner (a swap's other label), error_mm."""
    lines = [",".join(CORRUPTION_COLUMNS)]
    lines += [f"{c.kind},{c.frame},{c.marker},{c.partner},{1000 * c.error:.3f}" for c in corruptions]
    atomic_write_text(Path(path), "\n".join(lines) + "\n")


def read_corruptions(path: str | os.PathLike[str]) -> tuple[Corruption, ...]:
    """Read a truth_corruptions.csv written by `write_corruptions` (errors back in metres)."""
    import csv

    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return tuple(Corruption(r["kind"], int(r["frame"]), r["marker"], r["partner"], float(r["error_mm"]) / 1000)
                 for r in rows)
