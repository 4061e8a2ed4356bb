"""Synthetic open chains of rigid segments joined by ball joints (Hang, Lasenby & Li, Section IV).

A chain ⟨N1-N2-…-NL⟩ has L segments of length 1 along their local x axis and L−1 ball
joints; segment i carries Ni markers.  In segment i's own frame the segment runs from
x = 0 to x = 1: for 0 < i the proximal joint j(i−1) is at the origin, for i < L−1 the
distal joint j(i) is at (1, 0, 0).  So successive joints are exactly 1 apart, and the
first and last segments reach 1 beyond their single joint.

Geometry (drawn first, so a seed gives the same chain whatever `frames` or `noise`):

- marker local position (x, r cos φ, r sin φ) with x ~ U(0, 1), r ~ U(0.1, 0.4),
  φ ~ U(0, 2π); a segment's markers are redrawn until they are at least 0.1 apart, any
  3 or more of them are non-collinear (s2/s1 ≥ 0.1 of the centred point set's singular
  values), 4 or more are non-coplanar (s3/s1 ≥ 0.1), and the same holds for the markers
  together with each of the segment's joints (so a solved joint can stand in as a marker);
- each joint's rest rotation (child relative to parent): rotation vector ~ N(0, 0.4²) per
  component; the root's initial orientation is uniformly random.

Motion, over normalised time τ = f / (F − 1) ∈ [0, 1]:

- root position, per axis: c + v τ + Σ_{k=1,2} b_k sin(2π ν_k τ + ψ_k) with c ~ U(−1, 1),
  v ~ U(−1, 1), b_k ~ U(0, 0.5), ν_k ~ U(0.5, 2), ψ_k ~ U(0, 2π);
- the root's rotation and every joint's relative rotation are driven by a body-frame
  angular velocity whose components are each Σ_{k=1,2} a_k sin(2π ν_k τ + φ_k) with
  a_k ~ U(1.5, 4) rad per unit τ, ν_k ~ U(0.5, 2) cycles per trial, φ_k ~ U(0, 2π),
  integrated with rotation matrices (R ← R · exp([ω(τ_mid)]× Δτ)), giving a joint's rotation
  an excursion of about 1–2 rad from its rest pose over the trial.

The angular velocity must vary in direction: with a constant ω every joint rotates about
one fixed axis, i.e. behaves as a hinge in the data, and a ball joint's centre is then
only known up to a line (the axis) — unidentifiable.  Positions come from forward
kinematics, so the geometry is exact to rounding whatever the integration error.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

MIN_SEPARATION = 0.1  # markers on one segment at least this far apart
MIN_RATIO = 0.1  # minimum s2/s1 (3+ points) and s3/s1 (4+ points) of a segment's marker set
RADIAL = (0.1, 0.4)  # radial offset of markers from the segment axis
OMEGA_AMPLITUDE = (1.5, 4.0)  # rad per unit normalised time, per sinusoid and component
FREQUENCY = (0.5, 2.0)  # cycles per trial
REST_SIGMA = 0.4  # rad, per component of a joint's rest rotation vector


@dataclass(frozen=True)
class Chain:
    """A simulated chain: marker trajectories, their grouping, and the true joint centres."""

    markers: np.ndarray  # (F, M, 3) with Gaussian noise
    clean_markers: np.ndarray  # (F, M, 3) exact
    labels: tuple[str, ...]  # M marker labels 's<segment>m<k>'
    groups: dict[str, tuple[str, ...]]  # segment name 's<i>' -> its marker labels
    joints: tuple[tuple[str, str, str], ...]  # (joint name 'j<i>', parent segment, child segment)
    centres: np.ndarray  # (F, L-1, 3) true joint trajectories
    rotations: np.ndarray  # (F, L, 3, 3) segment orientations: world = R @ local + origin
    origins: np.ndarray  # (F, L, 3) segment frame origins (proximal joint; free end for segment 0)
    local: np.ndarray  # (M, 3) each marker's position in its segment's frame

    @property
    def segments(self) -> tuple[str, ...]:
        """Segment names, root first."""
        return tuple(self.groups)

    def points(self) -> dict[str, np.ndarray]:
        """Marker label -> (F, 3) noisy trajectory (a copy)."""
        return {lab: self.markers[:, k].copy() for k, lab in enumerate(self.labels)}


def _ratios(points: np.ndarray) -> tuple[float, float]:
    """(s2/s1, s3/s1) of the centred point set (P, 3)."""
    s = np.linalg.svd(points - points.mean(0), compute_uv=False)
    s = np.concatenate([s, np.zeros(3 - len(s))])
    return float(s[1] / s[0]), float(s[2] / s[0])


def _well_spread(points: np.ndarray) -> bool:
    """True if 3+ points are non-collinear and 4+ non-coplanar (by MIN_RATIO)."""
    if len(points) < 3:
        return True
    r2, r3 = _ratios(points)
    return r2 >= MIN_RATIO and (len(points) < 4 or r3 >= MIN_RATIO)


def _segment_markers(rng: np.random.Generator, n: int, joints: list[np.ndarray]) -> np.ndarray:
    """n marker positions (n, 3) in a segment frame, redrawn until in general position."""
    for _ in range(10_000):
        x = rng.uniform(0.0, 1.0, n)
        r = rng.uniform(*RADIAL, n)
        phi = rng.uniform(0.0, 2 * np.pi, n)
        pts = np.column_stack([x, r * np.cos(phi), r * np.sin(phi)])
        if n >= 2:
            d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
            if d[np.triu_indices(n, 1)].min() < MIN_SEPARATION:
                continue
        if _well_spread(pts) and all(_well_spread(np.vstack([pts, j])) for j in joints):
            return pts
    raise RuntimeError(f"could not place {n} markers in general position")  # pragma: no cover


def _angular_velocity(rng: np.random.Generator, n: int, tau: np.ndarray) -> np.ndarray:
    """(len(tau), n, 3) angular velocities: per component a sum of two random sinusoids."""
    a = rng.uniform(*OMEGA_AMPLITUDE, (2, n, 3))
    nu = rng.uniform(*FREQUENCY, (2, n, 3))
    ph = rng.uniform(0.0, 2 * np.pi, (2, n, 3))
    return np.sum(a * np.sin(2 * np.pi * nu * tau[:, None, None, None] + ph), axis=1)


def simulate_chain(
    markers_per_segment: Sequence[int],
    frames: int = 100,
    noise: float = 0.0,
    seed: int | np.random.Generator = 0,
) -> Chain:
    """Simulate the chain ⟨N1-…-NL⟩ (markers_per_segment) over `frames` frames; `noise` is the std of
    isotropic Gaussian marker noise in units of the joint spacing."""
    counts = [int(n) for n in markers_per_segment]
    if not counts or min(counts) < 1:
        raise ValueError("markers_per_segment: need at least one segment, each with at least one marker")
    if frames < 2:
        raise ValueError("frames: need at least 2")
    if noise < 0:
        raise ValueError("noise: must be >= 0")
    rng = np.random.default_rng(seed)
    L = len(counts)
    ex = np.array([1.0, 0.0, 0.0])

    # geometry
    local_list, seg_of, labels = [], [], []
    for i, n in enumerate(counts):
        joints = ([np.zeros(3)] if i > 0 else []) + ([ex] if i < L - 1 else [])
        local_list.append(_segment_markers(rng, n, joints))
        seg_of += [i] * n
        labels += [f"s{i}m{k}" for k in range(n)]
    local = np.vstack(local_list)
    seg_of_arr = np.array(seg_of)
    rest = Rotation.from_rotvec(rng.normal(0.0, REST_SIGMA, (L - 1, 3))) if L > 1 else None
    root0 = Rotation.random(random_state=rng)

    # motion: root translation, then rotations of the root (index 0) and the L-1 joints
    tau = np.linspace(0.0, 1.0, frames)
    c = rng.uniform(-1.0, 1.0, 3)
    v = rng.uniform(-1.0, 1.0, 3)
    b = rng.uniform(0.0, 0.5, (2, 3))
    nu = rng.uniform(*FREQUENCY, (2, 3))
    ps = rng.uniform(0.0, 2 * np.pi, (2, 3))
    root_pos = c + v * tau[:, None] + np.sum(b * np.sin(2 * np.pi * nu * tau[:, None, None] + ps), axis=1)
    tau_mid = 0.5 * (tau[1:] + tau[:-1])
    dtau = tau[1] - tau[0]
    steps = Rotation.from_rotvec((_angular_velocity(rng, L, tau_mid) * dtau).reshape(-1, 3))
    quats = np.empty((frames, L, 4))
    state = Rotation.concatenate([root0] + ([rest] if rest is not None else []))
    quats[0] = state.as_quat()
    for f in range(frames - 1):
        state = state * steps[f * L:(f + 1) * L]
        quats[f + 1] = state.as_quat()

    # forward kinematics
    rel = Rotation.from_quat(quats.reshape(-1, 4)).as_matrix().reshape(frames, L, 3, 3)
    R = np.empty_like(rel)
    R[:, 0] = rel[:, 0]
    for i in range(1, L):
        R[:, i] = R[:, i - 1] @ rel[:, i]
    origins = np.empty((frames, L, 3))
    origins[:, 0] = root_pos
    for i in range(1, L):
        origins[:, i] = origins[:, i - 1] + R[:, i - 1] @ ex
    centres = origins[:, 1:].copy()
    clean = np.einsum("fmij,mj->fmi", R[:, seg_of_arr], local) + origins[:, seg_of_arr]
    noisy = clean + rng.normal(0.0, noise, clean.shape) if noise > 0 else clean.copy()

    groups = {f"s{i}": tuple(f"s{i}m{k}" for k in range(n)) for i, n in enumerate(counts)}
    joints_t = tuple((f"j{i}", f"s{i}", f"s{i + 1}") for i in range(L - 1))
    return Chain(noisy, clean, tuple(labels), groups, joints_t, centres, R, origins, local)
