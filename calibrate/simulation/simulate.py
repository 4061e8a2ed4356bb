"""Synthetic squat and gait trials of a synthetic subject, with known truth.

The subject is the base model with random but plausible changes (segment scales
±10 %, joint centres ±15 mm per coordinate, hinge axes tilted by up to 5°, markers
±10 mm per coordinate).  The motion is repeated squats (hips, knees and ankles
together, pelvis dropping so the feet stay on the floor) with trunk, neck and arm
movement: every degree of freedom also follows its own slow sinusoid, so hips move in
abduction and rotation, shoulders and elbows through large arcs, and no two joints
move in lock-step.  Markers get Gaussian noise and, optionally, occlusion gaps.

`simulate_gait` is treadmill walking instead: the ranges of a normal gait cycle (hips, knees and
ankles through their usual arcs, arms swinging from the shoulders, elbows bending a little) and
nearly still forearms, wrists, neck and subtalar joints (a few degrees), as in a lab's walking
trial, where many joints hardly move.

`simulate_overhead` is serve- and throw-like arm arcs far above the head (shoulder abduction or
flexion to 155-172°, through the gimbal lock of the shoulder's flexion-adduction-rotation
sequence at 90° abduction) while the rest of the body makes smaller squat-like arcs.

What a lab adds (every option off by default, so that a seed's trial is unchanged): soft-tissue
artefact (`sta_mm`: each skin marker moves relative to its bone as a smooth function of the angles
of its segment's joints, by segment as published), a subject of a given stature (`height`),
occlusion gaps as a fraction of the marker samples (`gap_fraction`), swapped labels (`swaps`) and
single-frame spikes (`spikes`), with the corrupted samples listed in `Simulation.corruptions`.
`simulate_realistic` combines them.  Figures and references: docs/simulation.md.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import ModelError
from ..io.motion import Motion, write_motion_csv
from ..io.text import atomic_write_text
from ..io.trial import Trial, write_c3d
from ..model.kinematics import Kinematics, build_kinematics
from ..model.model import Model, Parameters, write_model

SCALE_RANGE = 0.10  # ± fraction
CENTRE_RANGE = 0.015  # ± m per coordinate
AXIS_TILT_DEG = 5.0  # max tilt of hinge axes
MARKER_RANGE = 0.010  # ± m per coordinate
SQUAT_PERIOD = 2.5  # s
GAIT_CYCLE = (1.0, 1.2)  # s: stride time, drawn per subject
# DoF-name suffix -> (offset, amplitude at the stride frequency, at twice it, own slow sinusoid), degrees:
# a normal gait cycle's ranges (Winter's); the last column keeps nearly still joints from being exactly still.
GAIT_TABLE = {
    "hip_flexion": (10, 22, 3, 1), "hip_adduction": (0, 5, 2, 1), "hip_rotation": (0, 5, 1, 1),
    "knee": (30, 25, 12, 1), "ankle": (0, 12, 5, 1), "subtalar": (0, 3, 1, 0.5),
    "lumbar_flexion": (3, 2, 1, 0.5), "lumbar_bending": (0, 3, 0, 0.5), "lumbar_rotation": (0, 5, 0, 0.5),
    "neck_flexion": (0, 1, 0, 1), "neck_bending": (0, 1, 0, 0.5), "neck_rotation": (0, 2, 0, 1),
    "shoulder_flexion": (5, 15, 0, 1), "shoulder_adduction": (-10, 3, 0, 0.5), "shoulder_rotation": (0, 3, 0, 0.5),
    "elbow": (30, 10, 0, 1), "radioulnar": (0, 2, 0, 0.5), "wrist_flexion": (0, 3, 0, 0.5),
    "wrist_deviation": (0, 2, 0, 0.5),
}


# Soft-tissue artefact: amplitude of a segment's markers as a multiple of `sta_mm` (the shank's), each
# marker drawn in STA_SPREAD times it.  Published figures behind them: docs/simulation.md.
STA_FACTOR = {"femur": 2.0, "tibia": 1.0, "pelvis": 0.6, "torso": 0.6, "humerus": 1.5, "ulna": 0.8, "radius": 0.8,
              "hand": 0.3, "head": 0.3, "talus": 0.3, "calcn": 0.3}
STA_ACROMION = 2.5  # torso markers within 6 cm (scaled) of a shoulder centre ride on the scapula
STA_SPREAD = (0.5, 1.5)
SIZE_SPREAD = 0.04  # ± fraction: per-segment factors around the overall one when a stature is asked for
HEIGHT_RANGE = (1.4, 2.2)  # m: statures the simulator accepts
REALISTIC_HEIGHTS = (1.5, 2.0)  # m: simulate_realistic draws the stature from this range
SWAP_FRAMES = (3, 10)  # frames of one swapped-label episode
SWAP_DISTANCE = (0.05, 0.20)  # m: neutral-pose distance of the markers a swap may exchange
SPIKE_SIZE = (0.030, 0.100)  # m: single-frame gross errors
GAP_SECONDS = (0.05, 0.6)  # s: one occlusion, as `occlusions` draws them
OVERHEAD_ARC = (1.6, 2.4)  # s: one serve or throw arc of an arm
OVERHEAD_PEAK = (155.0, 172.0)  # deg: shoulder flexion (serve) or abduction (throw) at the top of an arc
# DoF-name suffix -> fraction of its swept interval below the standing angle (0) in simulate_overhead's
# whole-body arcs (default 0.5: centred); the squat-coupled ones deepen with the squat.
REACH_START = {"hip_flexion": 0.15, "knee": 0.03, "ankle": 0.4, "lumbar_flexion": 0.25, "elbow": 0.05}
SQUAT_COUPLED = ("hip_flexion", "knee", "ankle", "lumbar_flexion")
_STREAMS = {"size": 1, "sta": 2, "gaps": 3, "corrupt": 4, "realistic": 5}


@dataclass(frozen=True)
class Corruption:
    """One corrupted marker sample of a simulated trial: what outlier rejection should catch."""

    kind: str  # 'swap' (two labels exchanged) or 'spike' (a single-frame gross error)
    frame: int  # 0-based
    marker: str  # the label whose position is wrong in this frame
    partner: str  # the other label of a swap; '' for a spike
    error: float  # m: distance of the observed position from where the skin marker was


@dataclass(frozen=True)
class Simulation:
    """A synthetic trial with its truth."""

    model: Model  # the base model the subject was derived from
    truth: Parameters  # the subject's geometric parameters (relative to `model`)
    motion: Motion  # true coordinates
    trial: Trial  # noisy markers with gaps, as a C3D would hold them
    clean_markers: np.ndarray  # (n_frames, n_markers, 3) noise- and gap-free markers of the bone model (truth)
    clean_centres: np.ndarray  # (n_frames, n_joints, 3) true joint-centre trajectories
    artefact: np.ndarray | None = None  # (n_frames, n_markers, 3) soft-tissue artefact (lab frame, m), if any
    sta_amplitude: np.ndarray | None = None  # (n_markers,) m: each marker's artefact amplitude, if any
    corruptions: tuple[Corruption, ...] = ()  # swapped and spiked samples, by frame
    stature: float | None = None  # m: the subject's stature when one was asked for (see `stature`)


def perturb_parameters(model: Model, rng: np.random.Generator) -> Parameters:
    """A random plausible subject: the base model's parameters with the documented changes."""
    p = model.parameters()
    scale = 1.0 + rng.uniform(-SCALE_RANGE, SCALE_RANGE, p.scale.shape)
    centre = p.centre + rng.uniform(-CENTRE_RANGE, CENTRE_RANGE, p.centre.shape)
    marker = p.marker + rng.uniform(-MARKER_RANGE, MARKER_RANGE, p.marker.shape)
    axis = p.axis.copy()
    hinge_dofs = [model.dof_index(j.dofs[0]) for j in model.joints if j.kind == "hinge"]
    for i in hinge_dofs:
        axis[i] = tilt(axis[i], math.radians(rng.uniform(0.3, 1.0) * AXIS_TILT_DEG), rng)
    return Parameters(scale, centre, axis, marker)


def tilt(axis: np.ndarray, angle: float, rng: np.random.Generator) -> np.ndarray:
    """Unit `axis` tilted by `angle` (rad) towards a random perpendicular direction."""
    a = axis / np.linalg.norm(axis)
    v = rng.normal(size=3)
    v -= (v @ a) * a
    v /= np.linalg.norm(v)
    return math.cos(angle) * a + math.sin(angle) * v


def squat_angles(model: Model, times: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Joint angles (n_frames, n_dofs): squats plus a distinct slow sinusoid per DoF, within limits."""
    deg = math.radians
    s = 0.5 * (1.0 - np.cos(2 * np.pi * times / SQUAT_PERIOD))  # 0 standing .. 1 deepest
    # DoF-name suffix -> (offset, squat amplitude, own amplitude), degrees.
    table = {
        "hip_flexion": (10, 90, 10), "hip_adduction": (-8, 0, 15), "hip_rotation": (0, 0, 20),
        "knee": (8, 105, 8), "ankle": (0, 25, 8), "subtalar": (0, 0, 12),
        "lumbar_flexion": (5, 20, 12), "lumbar_bending": (0, 0, 15), "lumbar_rotation": (0, 0, 20),
        "neck_flexion": (0, 0, 25), "neck_bending": (0, 0, 20), "neck_rotation": (0, 0, 35),
        "shoulder_flexion": (60, 0, 60), "shoulder_adduction": (-40, 0, 30), "shoulder_rotation": (0, 0, 40),
        "elbow": (60, 0, 50), "radioulnar": (0, 0, 50), "wrist_flexion": (0, 0, 35), "wrist_deviation": (5, 0, 15),
    }
    out = np.zeros((times.size, model.n_dofs))
    for i, d in enumerate(model.dofs):
        key = _generic_dof_name(d.name)
        off, sq, own = table.get(key, (0, 0, 20))
        freq = rng.uniform(0.13, 0.55)  # Hz; distinct per DoF
        phase = rng.uniform(0, 2 * np.pi)
        th = deg(off) + deg(sq) * s + deg(own) * np.sin(2 * np.pi * freq * times + phase)
        lo, hi = d.lower, d.upper
        if np.isfinite(lo) and np.isfinite(hi):
            margin = 0.02 * (hi - lo)
            th = np.clip(th, lo + margin, hi - margin)
        out[:, i] = th
    return out


def _generic_dof_name(name: str) -> str:
    """'hip_r_flexion' -> 'hip_flexion', 'knee_l' -> 'knee' (side removed)."""
    parts = [p for p in name.split("_") if p not in ("r", "l")]
    return "_".join(parts)


def gait_angles(model: Model, times: np.ndarray, cycle: float, rng: np.random.Generator) -> np.ndarray:
    """Joint angles (n_frames, n_dofs) of treadmill walking with stride time `cycle` (s): GAIT_TABLE's
    ranges, the left side half a cycle after the right, within limits."""
    deg = math.radians
    phase = 2 * np.pi * times / cycle
    out = np.zeros((times.size, model.n_dofs))
    for i, d in enumerate(model.dofs):
        off, a1, a2, own = GAIT_TABLE.get(_generic_dof_name(d.name), (0, 2, 0, 0.5))
        ph = phase + (np.pi if "_l_" in f"_{d.name}_" else 0.0)  # the left side half a stride later
        th = (deg(off) + deg(a1) * np.sin(ph) + deg(a2) * np.sin(2 * ph + 0.5)
              + deg(own) * np.sin(2 * np.pi * rng.uniform(0.2, 0.5) * times + rng.uniform(0, 2 * np.pi)))
        lo, hi = d.lower, d.upper
        if np.isfinite(lo) and np.isfinite(hi):
            th = np.clip(th, lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo))
        out[:, i] = th
    return out


def gait_root_orientation(times: np.ndarray, cycle: float, rng: np.random.Generator) -> np.ndarray:
    """Pelvis orientation (n_frames, 4 quaternion x, y, z, w) in walking: a random heading, with
    the pelvis's rotation, tilt and obliquity over the stride."""
    phase = 2 * np.pi * times / cycle
    yaw = rng.uniform(-np.pi, np.pi) + np.radians(5) * np.sin(phase)
    pitch = np.radians(3) * np.sin(2 * phase)
    roll = np.radians(4) * np.sin(phase + 1.0)
    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_quat()


def root_orientation(times: np.ndarray, squat: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Pelvis orientation (n_frames, 4 quaternion x, y, z, w): slow turning, tilt with the squat, sway."""
    yaw = rng.uniform(-np.pi, np.pi) + np.radians(40) * np.sin(2 * np.pi * 0.07 * times)
    pitch = np.radians(15) * squat + np.radians(4) * np.sin(2 * np.pi * 0.31 * times)
    roll = np.radians(6) * np.sin(2 * np.pi * 0.23 * times + 1.0)
    return Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll])).as_quat()


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


@dataclass(frozen=True)
class Lab:
    """What a lab adds to a simulated trial beyond white noise (all off by default)."""

    sta_mm: float = 0.0  # soft-tissue artefact level: the shank markers' mean amplitude, mm
    height: float | None = None  # m: the subject's stature (None: the base model's, as perturb_parameters draws it)
    gap_fraction: float = 0.0  # fraction of marker samples in occlusion gaps (0: none beyond `gaps`)
    swaps: int = 0  # episodes of two exchanged labels
    spikes: int = 0  # single-frame gross errors


def _check_args(frames: int, rate: float, noise_mm: float, lab: Lab | None = None, gaps: bool = False) -> None:
    if frames < 2:
        raise ValueError(f"frames: need at least 2, got {frames}")
    if not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"rate: must be a positive number of Hz, got {rate}")
    if not (noise_mm >= 0 and math.isfinite(noise_mm)):
        raise ValueError(f"noise_mm: must be >= 0, got {noise_mm}")
    if lab is None:
        return
    if not (lab.sta_mm >= 0 and math.isfinite(lab.sta_mm)):
        raise ValueError(f"sta_mm: must be >= 0 mm, got {lab.sta_mm}")
    if lab.height is not None and not (HEIGHT_RANGE[0] <= lab.height <= HEIGHT_RANGE[1]):
        raise ValueError(f"height: must be {HEIGHT_RANGE[0]:g}-{HEIGHT_RANGE[1]:g} m, got {lab.height}")
    if not (0.0 <= lab.gap_fraction <= 0.5):
        raise ValueError(f"gap_fraction: must be 0-0.5, got {lab.gap_fraction}")
    if lab.gap_fraction > 0 and gaps:
        raise ValueError("gaps and gap_fraction: ask for one kind of gaps, not both")
    for name in ("swaps", "spikes"):
        n = getattr(lab, name)
        if int(n) != n or n < 0:
            raise ValueError(f"{name}: must be a whole number >= 0, got {n}")


def _stream(seed: int, name: str) -> np.random.Generator:
    """An independent random stream per option, so that turning one on leaves the rest of the trial
    (subject, motion, noise, the other options) exactly as it was for the seed."""
    return np.random.default_rng([int(seed), _STREAMS[name]])


def simulate_squats(model: Model, frames: int = 1000, rate: float = 100.0, noise_mm: float = 1.0,
                    gaps: bool = False, seed: int = 0, *, sta_mm: float = 0.0, height: float | None = None,
                    gap_fraction: float = 0.0, swaps: int = 0, spikes: int = 0) -> Simulation:
    """Simulate a squat trial of a random subject derived from `model` (see module docstring).

    Keywords (all off by default): `sta_mm` soft-tissue artefact level (mm), `height` the subject's
    stature (m, 1.4-2.2), `gap_fraction` of marker samples in gaps, `swaps` swapped-label episodes,
    `spikes` single-frame gross errors."""
    lab = Lab(sta_mm, height, gap_fraction, swaps, spikes)
    _check_args(frames, rate, noise_mm, lab, gaps)
    rng = np.random.default_rng(seed)
    truth = _subject(model, rng, lab, seed)
    times = np.arange(frames) / rate
    angles = squat_angles(model, times, rng)
    squat = 0.5 * (1.0 - np.cos(2 * np.pi * times / SQUAT_PERIOD))
    quat = root_orientation(times, squat, rng)
    sway = 0.01 * np.column_stack([np.sin(2 * np.pi * 0.2 * times), np.sin(2 * np.pi * 0.17 * times + 2),
                                   np.zeros(frames)])
    # The pelvis drops and moves back as the subject squats: the ankles stay put (feet planted).
    return _observe(model, truth, times, angles, quat, sway, True, rate, noise_mm, gaps, rng, lab, seed)


def simulate_gait(model: Model, frames: int = 1000, rate: float = 100.0, noise_mm: float = 1.0,
                  gaps: bool = False, seed: int = 0, *, sta_mm: float = 0.0, height: float | None = None,
                  gap_fraction: float = 0.0, swaps: int = 0, spikes: int = 0) -> Simulation:
    """Simulate treadmill walking of a random subject derived from `model` (see module docstring):
    the subject as simulate_squats draws it for the same seed, the motion of gait_angles.
    Keywords as simulate_squats'."""
    lab = Lab(sta_mm, height, gap_fraction, swaps, spikes)
    _check_args(frames, rate, noise_mm, lab, gaps)
    rng = np.random.default_rng(seed)
    truth = _subject(model, rng, lab, seed)
    times = np.arange(frames) / rate
    cycle = float(rng.uniform(*GAIT_CYCLE))
    angles = gait_angles(model, times, cycle, rng)
    quat = gait_root_orientation(times, cycle, rng)
    phase = 2 * np.pi * times / cycle
    # The pelvis rises twice a stride and sways from side to side; the treadmill keeps it in place.
    bounce = np.column_stack([np.zeros(frames), 0.02 * np.sin(phase), 0.02 * np.cos(2 * phase)])
    return _observe(model, truth, times, angles, quat, bounce, False, rate, noise_mm, gaps, rng, lab, seed)


def simulate_overhead(model: Model, frames: int = 1000, rate: float = 100.0, noise_mm: float = 1.0,
                      gaps: bool = False, seed: int = 0, *, reach: float = 0.35, sta_mm: float = 0.0,
                      height: float | None = None, gap_fraction: float = 0.0, swaps: int = 0,
                      spikes: int = 0) -> Simulation:
    """Simulate serve- and throw-like arm arcs far overhead (overhead_angles) of the subject
    simulate_squats draws for the seed, the other joints sweeping `reach` of their ranges in
    squat-like arcs, the feet planted.  Keywords as simulate_squats'."""
    lab = Lab(sta_mm, height, gap_fraction, swaps, spikes)
    _check_args(frames, rate, noise_mm, lab, gaps)
    if not (0.0 < reach <= 0.95):
        raise ValueError(f"reach: must be a fraction of each joint's range in (0, 0.95], got {reach}")
    rng = np.random.default_rng(seed)
    truth = _subject(model, rng, lab, seed)
    times = np.arange(frames) / rate
    angles = overhead_angles(model, times, rng, reach)
    squat = 0.5 * (1.0 - np.cos(2 * np.pi * times / SQUAT_PERIOD))
    quat = root_orientation(times, (reach / 0.7) * squat, rng)
    sway = 0.01 * np.column_stack([np.sin(2 * np.pi * 0.2 * times), np.sin(2 * np.pi * 0.17 * times + 2),
                                   np.zeros(frames)])
    return _observe(model, truth, times, angles, quat, sway, True, rate, noise_mm, gaps, rng, lab, seed)


MOTIONS = {"squats": simulate_squats, "gait": simulate_gait, "overhead": simulate_overhead}


def simulate_realistic(model: Model, seed: int = 0, frames: int = 1000, rate: float = 100.0,
                       noise_mm: float = 1.0, *, motion: str = "overhead", reach: float = 0.7, sta_mm: float = 3.0,
                       height: float | None = None, gap_fraction: float = 0.05, swaps: int = 3,
                       spikes: int = 5, gaps: bool = False) -> Simulation:
    """A trial as a lab records it, for benchmarks: overhead arm arcs with every other joint sweeping
    70 % of its range in squat-like arcs (`motion`, `reach`), 3 mm soft-tissue artefact, a random
    stature in 1.5-2.0 m (unless `height`), 5 % of marker samples in gaps, 3 swapped-label episodes,
    5 spikes and 1 mm noise.  Every figure can be overridden (`gaps=True` with `gap_fraction=0`: the
    occlusions of `occlusions` instead)."""
    if motion not in MOTIONS:
        raise ValueError(f"motion: one of {', '.join(MOTIONS)}, got '{motion}'")
    if height is None:
        height = float(_stream(seed, "realistic").uniform(*REALISTIC_HEIGHTS))
    extra = {"reach": reach} if motion == "overhead" else {}
    return MOTIONS[motion](model, frames, rate, noise_mm, gaps, seed, sta_mm=sta_mm, height=height,
                           gap_fraction=gap_fraction, swaps=swaps, spikes=spikes, **extra)


def _subject(model: Model, rng: np.random.Generator, lab: Lab, seed: int) -> Parameters:
    """perturb_parameters' subject; with `lab.height`, its segments rescaled to that stature."""
    truth = perturb_parameters(model, rng)
    if lab.height is None:
        return truth
    return sized_subject(model, truth, lab.height, _stream(seed, "size"))


def sized_subject(model: Model, params: Parameters, height: float, rng: np.random.Generator,
                  spread: float = SIZE_SPREAD) -> Parameters:
    """`params` with every segment's scale replaced by c·(1 + u), u uniform in ±`spread` per segment
    (the proportions vary) and c the one overall factor that makes the stature (see `stature`)
    exactly `height` (m).  Joint centres, axes and marker offsets are kept (positions scale with c)."""
    s = 1.0 + rng.uniform(-spread, spread, params.scale.shape)
    p = Parameters(s, params.centre, params.axis, params.marker)
    c = height / stature(model, p)  # the stature is linear in the scales (every length is)
    return Parameters(c * s, params.centre, params.axis, params.marker)


def _human_landmarks() -> tuple[float, float, float]:
    """Neck, ankle and vertex heights of calibrate.model.human's reference subject (m)."""
    from ..model.human import _MID, _R

    return _MID["neck"][2], _R["ankle"][2], _MID["vertex"][2]


def stature(model: Model, params: Parameters, kin: Kinematics | None = None) -> float:
    """The stature (m) of a subject of a calibrate.model.human-style model: in the neutral pose, the
    height of the neck joint centre above the mean of the ankle centres, plus the sole-to-ankle and
    neck-to-vertex heights of calibrate.model.human's proportions (0.07 and 0.25 of the neck-to-ankle
    1.43 of its 1.75 m reference) sized to the base model and multiplied by the scales of the feet
    (calcn) and the head.  The base model itself: its generator's height (1.75 m for models/human.urdf)."""
    names = [j.name for j in model.joints]
    segs = [s.name for s in model.segments]
    need_j, need_s = ("neck", "ankle_r", "ankle_l"), ("head", "calcn_r", "calcn_l")
    if not all(n in names for n in need_j) or not all(n in segs for n in need_s):
        raise ModelError(f"{model.path}: a stature needs joints {', '.join(need_j)} and segments "
                         f"{', '.join(need_s)} (a calibrate.model.human model); leave the height out")
    kin = kin or build_kinematics(model)

    def neck_above_ankles(p: Parameters) -> float:
        _, c = kin.batch(np.zeros((1, model.nz)), np.array([[0.0, 0.0, 0.0, 1.0]]), p)
        z = c[0, :, 2]
        return float(z[names.index("neck")] - 0.5 * (z[names.index("ankle_r")] + z[names.index("ankle_l")]))

    neck, ankle, vertex = _human_landmarks()
    k0 = neck_above_ankles(model.parameters()) / (neck - ankle)  # the base model's size vs the reference
    foot = 0.5 * (params.scale[segs.index("calcn_r")] + params.scale[segs.index("calcn_l")])
    head = params.scale[segs.index("head")]
    return neck_above_ankles(params) + k0 * (ankle * foot + (vertex - neck) * head)


def overhead_angles(model: Model, times: np.ndarray, rng: np.random.Generator, reach: float = 0.35) -> np.ndarray:
    """Joint angles (n_frames, n_dofs): each arm alternates serve-like arcs (shoulder flexion to 155-172°)
    and throw-like arcs (abduction to 155-172°, i.e. adduction through -90°, the gimbal lock of the
    shoulder's flexion-adduction-rotation sequence, with the humerus turning about its long axis), the
    left arm half an arc after the right; every other DoF sweeps `reach` of its range (between its limits)
    in arcs coupled to squats (hips, knees, ankles, lumbar flexion) or its own slow sinusoid."""
    deg = math.radians
    squat = 0.5 * (1.0 - np.cos(2 * np.pi * times / SQUAT_PERIOD))
    out = np.zeros((times.size, model.n_dofs))
    arcs = {side: _arm_arcs(times, rng, delay) for side, delay in (("r", 0.0), ("l", 0.5 * OVERHEAD_ARC[0]))}
    for i, d in enumerate(model.dofs):
        key = _generic_dof_name(d.name)
        own = np.sin(2 * np.pi * rng.uniform(0.13, 0.55) * times + rng.uniform(0, 2 * np.pi))
        lo, hi = d.lower, d.upper
        if not (np.isfinite(lo) and np.isfinite(hi)):
            lo, hi = -np.pi, np.pi
        margin = 0.02 * (hi - lo)
        lo, hi = lo + margin, hi - margin
        side = "l" if "_l_" in f"_{d.name}_" else "r"
        if key in ("shoulder_flexion", "shoulder_adduction", "shoulder_rotation"):
            serve, throw, u_s, u_t, peak = arcs[side]
            rest = 1.0 - serve - throw
            if key == "shoulder_flexion":  # serve: up in front; throw: arm in the frontal plane
                th = (deg(15) + deg(10) * own) * rest + serve * np.radians(peak) + throw * deg(5)
            elif key == "shoulder_adduction":  # negative = abduction
                th = (deg(-15) + deg(8) * own) * rest + serve * deg(-10) - throw * np.radians(peak)
            else:  # the humerus turns out and in about its long axis during each arc
                th = (deg(15) * own * rest + deg(60) * np.sin(2 * np.pi * u_s) * np.sin(np.pi * u_s)
                      - deg(80) * np.sin(2 * np.pi * u_t) * np.sin(np.pi * u_t))
            out[:, i] = np.clip(th, lo, hi)
            continue
        span = reach * (hi - lo)
        below = REACH_START.get(key, 0.5)
        start = min(max(-below * span, lo), hi - span)  # the swept interval [start, start + span]
        o = 0.5 + 0.5 * own
        w = 0.75 * squat + 0.25 * o if key in SQUAT_COUPLED else o
        out[:, i] = start + span * w
    return out


def _arm_arcs(times: np.ndarray, rng: np.random.Generator, delay: float):
    """Serve and throw arcs of one arm: weights (F,) rising 0 -> 1 -> 0 as sin² over each arc
    (alternating, never overlapping), each arc's phase u in [0, 1] (0 outside) and its peak angle
    (deg, drawn in OVERHEAD_PEAK per arc; it changes only between arcs, where the weights are 0)."""
    serve, throw = np.zeros(times.size), np.zeros(times.size)
    u_s, u_t, peak = np.zeros(times.size), np.zeros(times.size), np.zeros(times.size)
    t0, k = delay + rng.uniform(0.1, 0.4), int(rng.integers(2))
    end = times[-1] if times.size else 0.0
    while t0 < end:
        dur = rng.uniform(*OVERHEAD_ARC)
        inside = (times >= t0) & (times <= t0 + dur)
        u = (times[inside] - t0) / dur
        (serve if k % 2 == 0 else throw)[inside] = np.sin(np.pi * u) ** 2
        (u_s if k % 2 == 0 else u_t)[inside] = u
        peak[inside] = rng.uniform(*OVERHEAD_PEAK)
        t0 += dur + rng.uniform(0.2, 0.6)
        k += 1
    return serve, throw, u_s, u_t, peak


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


def _swap_pairs(model: Model, neutral: np.ndarray) -> list[tuple[int, int]]:
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


def _corrupt(model: Model, observed: np.ndarray, skin: np.ndarray, neutral: np.ndarray, swaps: int, spikes: int,
             rng: np.random.Generator) -> tuple[Corruption, ...]:
    """Exchange labels in `swaps` episodes of SWAP_FRAMES frames and add `spikes` single-frame errors of
    SPIKE_SIZE to `observed` (in place), on visible samples, no sample twice; the corrupted samples."""
    n_frames = observed.shape[0]
    names = model.marker_names
    used = np.isnan(observed[..., 0])  # gaps and corrupted samples are off limits
    out: list[Corruption] = []
    pairs = _swap_pairs(model, neutral) if swaps else []
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


def _skin_markers(kin: Kinematics, Z: np.ndarray, quat: np.ndarray, truth: Parameters,
                  offsets: np.ndarray) -> np.ndarray:
    """Markers (F, M, 3) with per-frame marker offsets (F, M, 3; unscaled, segment frames)."""
    nf, nm = offsets.shape[:2]
    P = np.tile(truth.vector()[:, None], (1, nf))
    P[kin.model.layout.group("marker"), :] = offsets.reshape(nf, 3 * nm).T
    M, _ = kin.h.map(nf, "thread", 2)(Z.T, quat.T, P)
    return np.asarray(M).reshape(3, nf, nm).transpose(1, 2, 0)


def _observe(model: Model, truth: Parameters, times: np.ndarray, angles: np.ndarray, quat: np.ndarray,
             offset: np.ndarray, planted: bool, rate: float, noise_mm: float, gaps: bool,
             rng: np.random.Generator, lab: Lab | None = None, seed: int = 0) -> Simulation:
    """Markers and centres of `truth` moving with `angles` and root orientation `quat`, the root
    placed so that the ankles' mid-point sits 7 cm (scaled) above the origin — in every frame
    (`planted`, feet on the floor) or on average — plus `offset` (F, 3); then what `lab` asks for
    (soft-tissue artefact before the noise; gaps; swaps and spikes on visible samples), noise and gaps."""
    lab = lab or Lab()
    frames = times.size
    kin = build_kinematics(model)
    Z = np.hstack([np.zeros((frames, 6)), angles])
    markers, centres = kin.batch(Z, quat, truth)
    ankles = [model.joint_index(j.name) for j in model.joints if j.name.startswith("ankle")]
    if ankles:
        anchor = centres[:, ankles, :].mean(axis=1)
        if not planted:
            anchor = np.broadcast_to(anchor.mean(axis=0), anchor.shape)
        target = np.array([0.0, 0.0, 0.07]) * float(np.mean(truth.scale))
    else:  # a model without ankles: keep its root near 1 m
        anchor = np.zeros((frames, 3))
        target = np.array([0.0, 0.0, 1.0])
    root = target - anchor + offset
    markers = markers + root[:, None, :]
    centres = centres + root[:, None, :]
    motion = Motion(times, root, quat, angles, model.dof_names)
    skin, artefact, amp = markers, None, None
    if lab.sta_mm > 0:
        disp, amp = soft_tissue_artefact(model, angles, lab.sta_mm, _stream(seed, "sta"))
        seg = np.array([model.segment_index(mk.segment) for mk in model.markers])
        skin = _skin_markers(kin, Z, quat, truth, truth.marker[None] + disp / truth.scale[seg][None, :, None])
        skin = skin + root[:, None, :]
        artefact = skin - markers
    observed = skin + rng.normal(0.0, noise_mm / 1000.0, markers.shape)
    if gaps:
        observed[occlusions(frames, len(model.markers), rate, rng)] = np.nan
    if lab.gap_fraction > 0:
        observed[occlusions_fraction(frames, len(model.markers), rate, lab.gap_fraction,
                                     _stream(seed, "gaps"))] = np.nan
    corruptions: tuple[Corruption, ...] = ()
    if lab.swaps or lab.spikes:
        neutral = kin.markers(np.zeros(model.nz), np.array([0.0, 0.0, 0.0, 1.0]), truth)
        corruptions = _corrupt(model, observed, skin, neutral, lab.swaps, lab.spikes, _stream(seed, "corrupt"))
    height = stature(model, truth, kin) if lab.height is not None else None
    trial = Trial(labels=model.marker_names, markers=observed, rate=float(rate), first_frame=0, source=None)
    return Simulation(model, truth, motion, trial, markers, centres, artefact, amp, corruptions, height)


def simulate_static(model: Model, truth: Parameters, frames: int = 200, rate: float = 100.0, noise_mm: float = 1.0,
                    seed: int = 0) -> Simulation:
    """A static trial of the subject `truth` (e.g. ``simulate_squats(...).truth``): standing in the
    neutral pose, as a lab records before the movement trials, with a few millimetres of sway and a
    degree or so of postural drift in every joint (no joint moves enough to be located)."""
    if frames < 2:
        raise ValueError(f"frames: need at least 2, got {frames}")
    rng = np.random.default_rng(seed)
    times = np.arange(frames) / rate
    drift = np.radians(0.5) * np.sin(2 * np.pi * 0.1 * times[:, None] + rng.uniform(0, 2 * np.pi, model.n_dofs))
    lo = np.array([d.lower for d in model.dofs])
    hi = np.array([d.upper for d in model.dofs])
    angles = np.clip(drift, lo, hi)
    yaw = rng.uniform(-np.pi, np.pi)
    quat = Rotation.from_euler("ZYX", np.column_stack([np.full(frames, yaw), np.radians(1) * np.sin(times),
                                                       np.zeros(frames)])).as_quat()
    kin = build_kinematics(model)
    markers, centres = kin.batch(np.hstack([np.zeros((frames, 6)), angles]), quat, truth)
    root = np.array([0.0, 0.0, 0.95]) * float(np.mean(truth.scale)) + 0.003 * np.column_stack(
        [np.sin(2 * np.pi * 0.2 * times), np.cos(2 * np.pi * 0.15 * times), np.zeros(frames)])
    markers = markers + root[:, None, :]
    centres = centres + root[:, None, :]
    motion = Motion(times, root, quat, angles, model.dof_names)
    observed = markers + rng.normal(0.0, noise_mm / 1000.0, markers.shape)
    trial = Trial(labels=model.marker_names, markers=observed, rate=float(rate), first_frame=0, source=None)
    return Simulation(model, truth, motion, trial, markers, centres)


def joint_axes_world(model: Model, params: Parameters, motion: Motion) -> dict[str, np.ndarray]:
    """World direction (n_frames, 3) of every hinge joint's axis over a motion, for the model with
    parameters `params` (e.g. a simulation's truth): the reference for axis estimates."""
    import tempfile

    import pinocchio as pin

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "subject.urdf"
        write_model(model, path, params)
        subject = Model(path)
    pm = subject.pin
    data = pm.createData()
    hinges = [j for j in subject.joints if j.kind == "hinge"]
    dofs = [subject.dofs[subject.dof_index(j.dofs[0])] for j in hinges]
    fids = [pm.getFrameId(d.name) for d in dofs]
    out = {j.name: np.zeros((len(motion.times), 3)) for j in hinges}
    for f in range(len(motion.times)):
        q = subject.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.framesForwardKinematics(pm, data, q)
        for j, d, fid in zip(hinges, dofs, fids, strict=True):
            out[j.name][f] = data.oMf[fid].rotation @ d.axis
    return out


def write_simulation(sim: Simulation, out_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Write trial.c3d, truth.urdf and truth_motion.csv into `out_dir` (created if missing), and
    truth_corruptions.csv when the trial has swapped or spiked samples (see `write_corruptions`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"trial": out / "trial.c3d", "truth": out / "truth.urdf", "motion": out / "truth_motion.csv"}
    write_c3d(paths["trial"], sim.trial)
    write_model(sim.model, paths["truth"], sim.truth)
    write_motion_csv(paths["motion"], sim.motion)
    if sim.corruptions:
        paths["corruptions"] = out / "truth_corruptions.csv"
        write_corruptions(paths["corruptions"], sim.corruptions)
    return paths


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
