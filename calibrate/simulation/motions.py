"""Joint-angle trajectories of the simulated movements: squats, treadmill gait (a table of published
gait curves), overhead serve- and throw-like arm arcs; root orientations."""

from __future__ import annotations

import math

import numpy as np

from ..model.model import Model
from ..model.rotations import euler_quats

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
    "wrist_deviation": (0, 2, 0, 0.5), "sc_protraction": (0, 2, 0, 1), "sc_elevation": (3, 1, 0, 1),
}


OVERHEAD_ARC = (1.6, 2.4)  # s: one serve or throw arc of an arm


OVERHEAD_PEAK = (155.0, 172.0)  # deg: shoulder flexion (serve) or abduction (throw) at the top of an arc


# DoF-name suffix -> fraction of its swept interval below the standing angle (0) in simulate_overhead's
# whole-body arcs (default 0.5: centred); the squat-coupled ones deepen with the squat.
REACH_START = {"hip_flexion": 0.15, "knee": 0.03, "ankle": 0.4, "lumbar_flexion": 0.25, "elbow": 0.05}


SQUAT_COUPLED = ("hip_flexion", "knee", "ankle", "lumbar_flexion")


# A girdle's clavicle elevation per unit of the arm's elevation in simulate_overhead (models/human_girdle.urdf):
# the clavicle rises some 30 deg as the arm reaches overhead (the scapulohumeral rhythm's share of the
# sternoclavicular joint; Inman 1944, and after him most shoulder models).
GIRDLE_RHYTHM = 0.2


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
        "sc_protraction": (0, 0, 12), "sc_elevation": (10, 0, 10),
    }
    out = np.zeros((times.size, model.n_dofs))
    for i, d in enumerate(model.dofs):
        key, sign = dof_motion(d)
        off, sq, own = table.get(key, (0, 0, 20))
        freq = rng.uniform(0.13, 0.55)  # Hz; distinct per DoF
        phase = rng.uniform(0, 2 * np.pi)
        th = deg(off) + deg(sq) * s + deg(own) * np.sin(2 * np.pi * freq * times + phase)
        lo, hi = _flipped(d, sign)
        if np.isfinite(lo) and np.isfinite(hi):
            margin = 0.02 * (hi - lo)
            th = np.clip(th, lo + margin, hi - margin)
        out[:, i] = sign * th
    return held_locked(model, out)


def generic_dof_name(name: str) -> str:
    """'hip_r_flexion' -> 'hip_flexion', 'knee_l' -> 'knee' (side removed)."""
    parts = [p for p in name.split("_") if p not in ("r", "l")]
    return "_".join(parts)


# OpenSim's coordinate names (gait2392, Rajagopal2016, Hamner, MoBL-ARMS; side removed) -> the motion of the tables
# above they take; a leading "-": the coordinate turns the other way (lumbar_extension is the trunk's extension).
# Without them an imported model's knees and elbows took a generic ±20 deg sinusoid: its squats flexed the hips 100
# deg with the knees nearly straight.
OPENSIM_MOTIONS = {
    "knee_angle": "knee", "ankle_angle": "ankle", "subtalar_angle": "subtalar", "lumbar_extension": "-lumbar_flexion",
    "arm_flex": "shoulder_flexion", "arm_add": "shoulder_adduction", "arm_rot": "shoulder_rotation",
    "elbow_flex": "elbow", "elbow_flexion": "elbow", "pro_sup": "radioulnar", "wrist_flex": "wrist_flexion",
    "wrist_dev": "wrist_deviation", "shoulder_elv": "shoulder_flexion", "shoulder_rot": "shoulder_rotation",
}


def dof_motion(d) -> tuple[str, float]:
    """The tables' motion a DoF takes and its sign: its generic name (generic_dof_name), or an OpenSim coordinate's
    (OPENSIM_MOTIONS), turned the other way where the coordinate's range says its joint flexes negative (gait2392's
    knee_angle, -120 to 10 deg)."""
    key = generic_dof_name(d.name)
    mapped = OPENSIM_MOTIONS.get(key)
    if mapped is None:
        return key, 1.0
    sign = -1.0 if mapped.startswith("-") else 1.0
    mapped = mapped.lstrip("-")
    if mapped in ("knee", "elbow") and np.isfinite(d.lower) and d.upper < 0.35 and d.lower < -1.0:
        sign = -sign
    return mapped, sign


def held_locked(model: Model, angles: np.ndarray) -> np.ndarray:
    """`angles` with an OpenSim model's locked coordinates at their locked values in every frame (its subtalar and mtp
    joints in Rajagopal2016): a simulated subject turns no joint its model holds.  Driven, Rajagopal's squats turned
    its locked subtalars through +-12 deg, which its calibration, holding them, could not fit (marker RMS 3.45 mm at
    1 mm noise, the right ankle's angle 5.5 deg RMS off)."""
    if "<opensim" not in model.text:
        return angles
    from ..io.osim_info import osim_info

    info = osim_info(model)
    for name, value in (info.locked.items() if info is not None else ()):
        if name in model.dof_names:
            angles[:, model.dof_index(name)] = value
    return angles


def _flipped(d, sign: float) -> tuple[float, float]:
    """The DoF's limits as the motion turns (negated and swapped for sign -1)."""
    return (d.lower, d.upper) if sign > 0 else (-d.upper, -d.lower)


def gait_angles(model: Model, times: np.ndarray, cycle: float, rng: np.random.Generator) -> np.ndarray:
    """Joint angles (n_frames, n_dofs) of treadmill walking with stride time `cycle` (s): GAIT_TABLE's
    ranges, the left side half a cycle after the right, within limits."""
    deg = math.radians
    phase = 2 * np.pi * times / cycle
    out = np.zeros((times.size, model.n_dofs))
    for i, d in enumerate(model.dofs):
        key, sign = dof_motion(d)
        off, a1, a2, own = GAIT_TABLE.get(key, (0, 2, 0, 0.5))
        ph = phase + (np.pi if "_l_" in f"_{d.name}_" else 0.0)  # the left side half a stride later
        th = (deg(off) + deg(a1) * np.sin(ph) + deg(a2) * np.sin(2 * ph + 0.5)
              + deg(own) * np.sin(2 * np.pi * rng.uniform(0.2, 0.5) * times + rng.uniform(0, 2 * np.pi)))
        lo, hi = _flipped(d, sign)
        if np.isfinite(lo) and np.isfinite(hi):
            th = np.clip(th, lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo))
        out[:, i] = sign * th
    return held_locked(model, out)


def gait_root_orientation(times: np.ndarray, cycle: float, rng: np.random.Generator) -> np.ndarray:
    """Pelvis orientation (n_frames, 4 quaternion x, y, z, w) in walking: a random heading, with
    the pelvis's rotation, tilt and obliquity over the stride."""
    phase = 2 * np.pi * times / cycle
    yaw = rng.uniform(-np.pi, np.pi) + np.radians(5) * np.sin(phase)
    pitch = np.radians(3) * np.sin(2 * phase)
    roll = np.radians(4) * np.sin(phase + 1.0)
    return euler_quats("ZYX", np.column_stack([yaw, pitch, roll]))


def root_orientation(times: np.ndarray, squat: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Pelvis orientation (n_frames, 4 quaternion x, y, z, w): slow turning, tilt with the squat, sway."""
    yaw = rng.uniform(-np.pi, np.pi) + np.radians(40) * np.sin(2 * np.pi * 0.07 * times)
    pitch = np.radians(15) * squat + np.radians(4) * np.sin(2 * np.pi * 0.31 * times)
    roll = np.radians(6) * np.sin(2 * np.pi * 0.23 * times + 1.0)
    return euler_quats("ZYX", np.column_stack([yaw, pitch, roll]))


def overhead_angles(model: Model, times: np.ndarray, rng: np.random.Generator, reach: float = 0.35) -> np.ndarray:
    """Joint angles (n_frames, n_dofs): each arm alternates serve-like arcs (shoulder flexion to 155-172°)
    and throw-like arcs (abduction to 155-172°, i.e. adduction through -90°, the gimbal lock of the
    shoulder's flexion-adduction-rotation sequence, with the humerus turning about its long axis), the
    left arm half an arc after the right; every other DoF sweeps `reach` of its range (between its limits)
    in arcs coupled to squats (hips, knees, ankles, lumbar flexion) or its own slow sinusoid."""
    deg = math.radians
    squat = 0.5 * (1.0 - np.cos(2 * np.pi * times / SQUAT_PERIOD))
    out = np.zeros((times.size, model.n_dofs))
    arcs = {side: arm_arcs(times, rng, delay) for side, delay in (("r", 0.0), ("l", 0.5 * OVERHEAD_ARC[0]))}
    for i, d in enumerate(model.dofs):
        key, sign = dof_motion(d)
        own = np.sin(2 * np.pi * rng.uniform(0.13, 0.55) * times + rng.uniform(0, 2 * np.pi))
        lo, hi = _flipped(d, sign)
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
            out[:, i] = sign * np.clip(th, lo, hi)
            continue
        if key in ("sc_elevation", "sc_protraction"):  # a girdle's clavicle rises with the arm (GIRDLE_RHYTHM)
            serve, throw, _, _, peak = arcs[side]
            if key == "sc_elevation":
                th = deg(5) + deg(3) * own + GIRDLE_RHYTHM * (serve + throw) * np.radians(peak)
            else:  # forward in a serve, back in a throw
                th = deg(4) * own + deg(12) * (serve - throw)
            out[:, i] = sign * np.clip(th, lo, hi)
            continue
        span = reach * (hi - lo)
        below = REACH_START.get(key, 0.5)
        start = min(max(-below * span, lo), hi - span)  # the swept interval [start, start + span]
        o = 0.5 + 0.5 * own
        w = 0.75 * squat + 0.25 * o if key in SQUAT_COUPLED else o
        out[:, i] = sign * (start + span * w)
    return held_locked(model, out)


def arm_arcs(times: np.ndarray, rng: np.random.Generator, delay: float):
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
