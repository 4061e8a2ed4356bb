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

from calibrate.io.measurements import (
    DEFAULT_MARKER_DIAMETER,
    SubjectMeasurements,
    lateral_distance,
    lateral_markers_of,
)
from calibrate.simulation.artefacts import (
    Corruption,
    corrupt,
    occlusions,
    occlusions_fraction,
    skin_markers,
    soft_tissue_artefact,
    write_corruptions,
)
from calibrate.simulation.motions import (
    GAIT_CYCLE,
    SQUAT_PERIOD,
    gait_angles,
    gait_root_orientation,
    overhead_angles,
    root_orientation,
    squat_angles,
)
from calibrate.simulation.subject import perturb_parameters, sized_subject, stature

from ..io.c3d import C3D_MAX_FRAMES, write_c3d
from ..io.motion import Motion, write_motion_csv
from ..io.trc import write_trc
from ..io.trial import Trial
from ..model.blocks import FrameLayout
from ..model.hinges import hinge_lines_world, joint_axes_world  # noqa: F401 - re-exported: the simulator's API
from ..model.kinematics import build_kinematics
from ..model.model import Model, Parameters, write_model
from ..model.rotations import euler_quats

# m: statures the simulator accepts: a child's (0.9 m, some four years old) to a tall adult's, the base model's segments
# scaled to it (a child's head and trunk are larger against its legs than an adult's: the proportions vary by +-4 %
# only, docs/simulation.md)
HEIGHT_RANGE = (0.9, 2.2)


REALISTIC_HEIGHTS = (1.5, 2.0)  # m: simulate_realistic draws the stature from this range


_STREAMS = {"size": 1, "sta": 2, "gaps": 3, "corrupt": 4, "realistic": 5, "measure": 6}


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


@dataclass(frozen=True)
class Lab:
    """What a lab adds to a simulated trial beyond white noise (all off by default)."""

    sta_mm: float = 0.0  # soft-tissue artefact level: the shank markers' mean amplitude, mm
    height: float | None = None  # m: the subject's stature (None: the base model's, as perturb_parameters draws it)
    gap_fraction: float = 0.0  # fraction of marker samples in occlusion gaps (0: none beyond `gaps`)
    swaps: int = 0  # episodes of two exchanged labels
    spikes: int = 0  # single-frame gross errors
    measured: bool = False  # the subject's knee, ankle and elbow widths (a caliper's) written with the trial


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
                    gap_fraction: float = 0.0, swaps: int = 0, spikes: int = 0, measured: bool = False) -> Simulation:
    """Simulate a squat trial of a random subject derived from `model` (see module docstring).

    Keywords (all off by default): `sta_mm` soft-tissue artefact level (mm), `height` the subject's
    stature (m, 0.9-2.2), `gap_fraction` of marker samples in gaps, `swaps` swapped-label episodes,
    `spikes` single-frame gross errors, `measured` the lab's caliper measurements written with the trial
    (lab_measurements)."""
    lab = Lab(sta_mm, height, gap_fraction, swaps, spikes, measured)
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
                  gap_fraction: float = 0.0, swaps: int = 0, spikes: int = 0, measured: bool = False) -> Simulation:
    """Simulate treadmill walking of a random subject derived from `model` (see module docstring):
    the subject as simulate_squats draws it for the same seed, the motion of gait_angles.
    Keywords as simulate_squats'."""
    lab = Lab(sta_mm, height, gap_fraction, swaps, spikes, measured)
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
                      spikes: int = 0, measured: bool = False) -> Simulation:
    """Simulate serve- and throw-like arm arcs far overhead (overhead_angles) of the subject
    simulate_squats draws for the seed, the other joints sweeping `reach` of their ranges in
    squat-like arcs, the feet planted.  Keywords as simulate_squats'."""
    lab = Lab(sta_mm, height, gap_fraction, swaps, spikes, measured)
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
                       spikes: int = 5, gaps: bool = False, measured: bool = True) -> Simulation:
    """A trial as a lab records it, for benchmarks: overhead arm arcs with every other joint sweeping
    70 % of its range in squat-like arcs (`motion`, `reach`), 3 mm soft-tissue artefact, a random
    stature in 1.5-2.0 m (unless `height`), 5 % of marker samples in gaps, 3 swapped-label episodes,
    5 spikes, 1 mm noise, and the lab's knee, ankle and elbow widths (`measured`, lab_measurements).
    Every figure can be overridden (`gaps=True` with `gap_fraction=0`: the
    occlusions of `occlusions` instead)."""
    if motion not in MOTIONS:
        raise ValueError(f"motion: one of {', '.join(MOTIONS)}, got '{motion}'")
    if height is None:
        height = float(_stream(seed, "realistic").uniform(*REALISTIC_HEIGHTS))
    extra = {"reach": reach} if motion == "overhead" else {}
    return MOTIONS[motion](model, frames, rate, noise_mm, gaps, seed, sta_mm=sta_mm, height=height,
                           gap_fraction=gap_fraction, swaps=swaps, spikes=spikes, measured=measured, **extra)


def _subject(model: Model, rng: np.random.Generator, lab: Lab, seed: int) -> Parameters:
    """perturb_parameters' subject; with `lab.height`, its segments rescaled to that stature."""
    truth = perturb_parameters(model, rng)
    if lab.height is None:
        return truth
    return sized_subject(model, truth, lab.height, _stream(seed, "size"))


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
    Z = FrameLayout.coordinates(np.zeros((frames, 3)), angles)  # the root at the origin, turned by quat
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
        skin = skin_markers(kin, Z, quat, truth, truth.marker[None] + disp / truth.scale[seg][None, :, None])
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
        corruptions = corrupt(model, observed, skin, neutral, lab.swaps, lab.spikes, _stream(seed, "corrupt"))
    height = stature(model, truth, kin) if lab.height is not None else None
    measurements = lab_measurements(model, truth, height, _stream(seed, "measure")) if lab.measured else None
    trial = Trial(labels=model.marker_names, markers=observed, rate=float(rate), first_frame=0, source=None,
                  measurements=measurements)
    return Simulation(model, truth, motion, trial, markers, centres, artefact, amp, corruptions, height)


CALIPER_SD = 0.002  # m: a measured joint width's error (caliper and palpation of the epicondyles, malleoli)


def lab_measurements(model: Model, truth: Parameters, height: float | None,
                     rng: np.random.Generator) -> SubjectMeasurements:
    """What a Plug-in Gait lab measures on the subject `truth`: each knee, ankle and elbow width whose lateral
    marker (KNE, ANK, ELB) the model carries — twice the true lateral marker's distance from the joint centre
    along the true axis less the marker's radius, plus a caliper's error (CALIPER_SD) — and the stature when one
    was asked for.  The width a lab would enter for the subject calibrate.io.measurements reads back."""
    base = model.parameters()
    widths = {}
    for name, marker in lateral_markers_of(model):
        d = lateral_distance(model, truth, base, name, marker)
        widths[name] = max(2.0 * (d - DEFAULT_MARKER_DIAMETER / 2) + float(rng.normal(0.0, CALIPER_SD)), 0.02)
    return SubjectMeasurements(height=None if height is None else float(height), widths=widths,
                               source="the simulated lab's measurements")


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
    quat = euler_quats("ZYX", np.column_stack([np.full(frames, yaw), np.radians(1) * np.sin(times), np.zeros(frames)]))
    kin = build_kinematics(model)
    markers, centres = kin.batch(FrameLayout.coordinates(np.zeros((frames, 3)), angles), quat, truth)
    root = np.array([0.0, 0.0, 0.95]) * float(np.mean(truth.scale)) + 0.003 * np.column_stack(
        [np.sin(2 * np.pi * 0.2 * times), np.cos(2 * np.pi * 0.15 * times), np.zeros(frames)])
    markers = markers + root[:, None, :]
    centres = centres + root[:, None, :]
    motion = Motion(times, root, quat, angles, model.dof_names)
    observed = markers + rng.normal(0.0, noise_mm / 1000.0, markers.shape)
    trial = Trial(labels=model.marker_names, markers=observed, rate=float(rate), first_frame=0, source=None)
    return Simulation(model, truth, motion, trial, markers, centres)


def write_simulation(sim: Simulation, out_dir: str | os.PathLike[str]) -> dict[str, Path]:
    """Write trial.c3d (trial.trc if it has more frames than a C3D file holds, C3D_MAX_FRAMES),
    truth.urdf and truth_motion.csv into `out_dir` (created if missing), and truth_corruptions.csv
    when the trial has swapped or spiked samples (see `write_corruptions`)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    long = sim.trial.n_frames > C3D_MAX_FRAMES
    paths = {"trial": out / ("trial.trc" if long else "trial.c3d"), "truth": out / "truth.urdf",
             "motion": out / "truth_motion.csv"}
    (write_trc if long else write_c3d)(paths["trial"], sim.trial)
    write_model(sim.model, paths["truth"], sim.truth)
    write_motion_csv(paths["motion"], sim.motion)
    if sim.corruptions:
        paths["corruptions"] = out / "truth_corruptions.csv"
        write_corruptions(paths["corruptions"], sim.corruptions)
    return paths
