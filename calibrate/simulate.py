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
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .kinematics import build_kinematics
from .model import Model, Parameters, write_model
from .motion import Motion, write_motion_csv
from .trial import Trial, write_c3d

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


@dataclass(frozen=True)
class Simulation:
    """A synthetic trial with its truth."""

    model: Model  # the base model the subject was derived from
    truth: Parameters  # the subject's geometric parameters (relative to `model`)
    motion: Motion  # true coordinates
    trial: Trial  # noisy markers with gaps, as a C3D would hold them
    clean_markers: np.ndarray  # (n_frames, n_markers, 3) noise- and gap-free markers
    clean_centres: np.ndarray  # (n_frames, n_joints, 3) true joint-centre trajectories


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


def _check_args(frames: int, rate: float, noise_mm: float) -> None:
    if frames < 2:
        raise ValueError(f"frames: need at least 2, got {frames}")
    if not (rate > 0 and math.isfinite(rate)):
        raise ValueError(f"rate: must be a positive number of Hz, got {rate}")
    if not (noise_mm >= 0 and math.isfinite(noise_mm)):
        raise ValueError(f"noise_mm: must be >= 0, got {noise_mm}")


def simulate_squats(model: Model, frames: int = 1000, rate: float = 100.0, noise_mm: float = 1.0,
                    gaps: bool = False, seed: int = 0) -> Simulation:
    """Simulate a squat trial of a random subject derived from `model` (see module docstring)."""
    _check_args(frames, rate, noise_mm)
    rng = np.random.default_rng(seed)
    truth = perturb_parameters(model, rng)
    times = np.arange(frames) / rate
    angles = squat_angles(model, times, rng)
    squat = 0.5 * (1.0 - np.cos(2 * np.pi * times / SQUAT_PERIOD))
    quat = root_orientation(times, squat, rng)
    sway = 0.01 * np.column_stack([np.sin(2 * np.pi * 0.2 * times), np.sin(2 * np.pi * 0.17 * times + 2),
                                   np.zeros(frames)])
    # The pelvis drops and moves back as the subject squats: the ankles stay put (feet planted).
    return _observe(model, truth, times, angles, quat, sway, True, rate, noise_mm, gaps, rng)


def simulate_gait(model: Model, frames: int = 1000, rate: float = 100.0, noise_mm: float = 1.0,
                  gaps: bool = False, seed: int = 0) -> Simulation:
    """Simulate treadmill walking of a random subject derived from `model` (see module docstring):
    the subject as simulate_squats draws it for the same seed, the motion of gait_angles."""
    _check_args(frames, rate, noise_mm)
    rng = np.random.default_rng(seed)
    truth = perturb_parameters(model, rng)
    times = np.arange(frames) / rate
    cycle = float(rng.uniform(*GAIT_CYCLE))
    angles = gait_angles(model, times, cycle, rng)
    quat = gait_root_orientation(times, cycle, rng)
    phase = 2 * np.pi * times / cycle
    # The pelvis rises twice a stride and sways from side to side; the treadmill keeps it in place.
    bounce = np.column_stack([np.zeros(frames), 0.02 * np.sin(phase), 0.02 * np.cos(2 * phase)])
    return _observe(model, truth, times, angles, quat, bounce, False, rate, noise_mm, gaps, rng)


def _observe(model: Model, truth: Parameters, times: np.ndarray, angles: np.ndarray, quat: np.ndarray,
             offset: np.ndarray, planted: bool, rate: float, noise_mm: float, gaps: bool,
             rng: np.random.Generator) -> Simulation:
    """Markers and centres of `truth` moving with `angles` and root orientation `quat`, the root
    placed so that the ankles' mid-point sits 7 cm (scaled) above the origin — in every frame
    (`planted`, feet on the floor) or on average — plus `offset` (F, 3); then noise and gaps."""
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
    observed = markers + rng.normal(0.0, noise_mm / 1000.0, markers.shape)
    if gaps:
        observed[occlusions(frames, len(model.markers), rate, rng)] = np.nan
    trial = Trial(labels=model.marker_names, markers=observed, rate=float(rate), first_frame=0, source=None)
    return Simulation(model, truth, motion, trial, markers, centres)


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
    """Write trial.c3d, truth.urdf and truth_motion.csv into `out_dir` (created if missing)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"trial": out / "trial.c3d", "truth": out / "truth.urdf", "motion": out / "truth_motion.csv"}
    write_c3d(paths["trial"], sim.trial)
    write_model(sim.model, paths["truth"], sim.truth)
    write_motion_csv(paths["motion"], sim.motion)
    return paths
