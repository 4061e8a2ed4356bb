"""The options of the least-squares problem (ProblemOptions, with its Priors) and of the Levenberg–Marquardt
solver (SolverOptions): typed views of the user's flat Settings (calibrate.problem.settings), each given only
to the part that reads it.  Units: metres, radians."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from ..model.blocks import GROUPS

LOSSES = ("linear", "huber", "cauchy")


NOISE_DEFAULT = 0.001  # m: Settings.noise unless given (then learnt from the data: Settings.learn_noise)


def _positive(name: str, v: object) -> None:
    """Raise ValueError unless `v` is a positive finite number."""
    if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
        raise ValueError(f"{name}: must be a positive number, got {v!r}")


@dataclass(frozen=True)
class Priors:
    """Standard deviations of the priors that pull p towards the base model."""

    marker: float = 0.02  # m: how far a subject's marker may sit from the base model's place
    centre: float = 0.02  # m: same for a joint centre
    axis: float = math.radians(10.0)  # rad: tilt of a hinge axis
    scale: float = 0.25  # fraction: a segment's scale factor about the subject's size (the segments' mean scale)
    size: float = 0.25  # fraction: the subject's size about the base model's (0: each segment's scale about 1)
    # Left/right symmetry (segments and joints named *_l / *_r; 0: off): SD of the difference between
    # a left segment's scale factor and its right partner's (fraction), and between a left joint centre
    # and its right partner's mirrored through the sagittal plane (m, at the subject's scale), each
    # counted relative to the base model's own asymmetry.  Soft-tissue artefact pulls the two sides
    # apart by different amounts; a subject's bones are symmetric to a few per cent.
    symmetry_scale: float = 0.05
    symmetry_centre: float = 0.02
    # A measured joint width (ProblemOptions.lateral_markers): SD of the distance along the hinge axis
    # from the lateral marker to the joint centre (m; 0: the measurements are not used).  A caliper reads
    # a knee to a few mm; the marker sits on skin over the epicondyle or malleolus.
    width: float = 0.005
    # Where no width was measured: SD of a knee's or ankle's lateral marker's distance along the hinge axis from the
    # centre about the base model's, at the segment's scale (m; 0: off; Problem.slide_centres, the joints the
    # pipeline names: calibrate.calibration.pipeline.population_widths).  No motion places a hinge along its axis;
    # left to the other priors (the centre's, the child segment's markers' and centres'), LKNE ended up to 21 mm
    # medial of its knee's centre on real walks.  The public Plug-in Gait sessions' measured widths (seven
    # subjects, 1.34-1.79 m) put the lateral marker 52-79 mm from the knee's centre and 35-52 mm from the ankle's:
    # SDs of 8 and 6 mm about their means, the base model's 55 and 41 mm within one of them (docs/benchmarks.md).
    population_width: float = 0.008
    # A hinge's lateral marker (Plug-in Gait's KNE, ANK, ELB on the segment the knee, ankle or elbow hangs from)
    # where the hinge's axis is held (a static alone, a joint the trials do not show moving, Settings.hold_axes):
    # SD of the marker's distance from the axis line through the centre (m, at the segment's scale; 0: off).  The
    # marker sits over the epicondyle or malleolus, which the flexion axis passes through (Plug-in Gait puts it
    # on the axis); with no motion to place the axis, the priors alone otherwise left the knee centres of real
    # statics 11-80 mm off the line through KNE (docs/benchmarks.md, "A static alone").
    on_axis: float = 0.010
    # A hinge whose parent segment carries two markers straddling its centre along its axis (the femoral or humeral
    # epicondyles, the malleoli; calibrate.problem.priors.straddling_pairs): SD of the angle between its axis and the
    # line through the two (rad; 0: off).  The line is the lab's anatomical flexion axis (Grood & Suntay; the ISB's);
    # the transepicondylar axis lies within a few degrees of the knee's flexion axis (Churchill et al. 1998), and
    # palpated epicondyles are placed to 5-15 mm over a 90-100 mm width (Della Croce et al. 1999).
    pair_axis: float = math.radians(5.0)
    # A knee whose axis the motion calibrates: SD of its centre's distance from the axis line through its anatomical
    # landmarks (m, at the segment's scale; 0: off), the midpoint of its epicondyle markers where the trials show
    # both (calibrate.problem.priors.straddling_pairs), else its Plug-in Gait lateral marker KNE, as Plug-in Gait, the
    # CGM and the ISB place it.  The motion places a hinge across its axis, but the thigh's skin markers slide with
    # the knee's flexion (rigid-body artefact ~10 deg and ~18 mm; a marker-based knee helical axis ~25 mm off the
    # bone's, Bonci et al. 2021 on fluoroscopy): real walks put the knee 13-37 mm distal of its epicondyles, the tibia
    # 15 % short (docs/benchmarks.md).  The fitted axis's own SD is a few mm; palpated epicondyles are placed to
    # 5-15 mm (Della Croce et al. 1999) against a motion error several times its SD.
    knee_landmark: float = 0.001
    # An ankle whose axis the motion calibrates, where the trials show both malleoli's markers (a pair straddling
    # it, calibrate.problem.priors.straddling_pairs): SD of its centre's distance from the axis line through their
    # midpoint, at the base model's offset (m, at the segment's scale; 0: off), as the ISB and Plug-in Gait with a
    # medial malleolus marker place it.  The foot's two or three markers cannot place the ankle across its axis against
    # the subtalar beside it (the report's "held by the prior": a posterior SD of 11-14 mm on real walks), and the
    # scaled base model's place put real ankles 8-43 mm from their malleoli (docs/benchmarks.md).
    ankle_landmark: float = 0.001
    # A joint-centre marker (calibrate.problem.priors.joint_centre_markers: the base model puts it within
    # JOINT_MARKER_RADIUS of a joint centre of its segment, e.g. OpenSim's R_HJC at the femur's origin): a
    # point the lab computed at that centre, not skin.  SD of its offset from the centre about the base
    # model's (m; 0: an ordinary marker, held by `marker` alone).
    joint_marker: float = 0.001
    # A held joint centre (ProblemOptions.hold_centres): SD of its offset from the centroid of its parent segment's
    # seen markers about the base model's (m; the base offset at the size of those markers' own layout).
    held_centre: float = 0.0001
    # A placeholder marker (calibrate.problem.priors.placeholder_markers: the base model puts it at one place with
    # other markers of its segment, as AddBiomechanics' OpenSim models (Lai-Uhlrich 2022 among them) put each thigh
    # and shank cluster, for OpenSim's marker placer to move): its place says nothing of the subject, so it is held
    # this loosely (m; the data place it), and neither sizes its segment nor turns its frame.
    placeholder: float = 0.25


@dataclass(frozen=True)
class ProblemOptions:
    """What the least-squares problem is (calibrate.problem.problem.Problem reads these and nothing else):
    the free parameter groups, the markers' noise, the robust loss, the priors, locked coordinates, held
    axes and segments, and whether the per-frame function is compiled (the meanings of Settings' fields of
    the same names)."""

    free: tuple[str, ...] = GROUPS
    noise: float = NOISE_DEFAULT  # m
    loss: str = "linear"
    loss_scale: float = 3.0  # in units of `noise`
    priors: Priors = field(default_factory=Priors)
    marker_noise: tuple[tuple[str, float], ...] = ()  # ((label, SD in m), ...) or a dict
    lock: tuple[tuple[str, float], ...] = ()  # ((DoF, angle in rad), ...), a dict, or DoF names (held at 0)
    hold_axes: tuple[str, ...] = ()
    hold_segments: tuple[str, ...] = ()
    hold_centres: tuple[str, ...] = ()  # joints whose centre keeps the base model's place (Priors.held_centre)
    # Where along its axis a hinge's centre lies, which no marker shows (Problem.slide_centres), as the lab
    # measured it: ((hinge joint, the lateral marker on its parent segment, that marker's distance from
    # the centre along the axis in m), ...) — Plug-in Gait's half knee or ankle width plus the marker's
    # radius (calibrate.io.measurements); the pipeline fills it from the trials' measurements.
    lateral_markers: tuple[tuple[str, str, float], ...] = ()
    compile: bool = True
    # Memory (MB) for the frames' blocks of the normal equations at once; a longer trial's are formed chunk
    # by chunk, and again when a pass needs them (calibrate.solve.chunks): ~170 kB per frame, full body.
    memory_mb: float = 200.0

    def __post_init__(self) -> None:
        for field_, what in (("hold_axes", "DoF"), ("hold_centres", "joint")):
            hold = getattr(self, field_)
            hold = (hold,) if isinstance(hold, str) else hold
            for name in hold:
                if not isinstance(name, str):
                    raise ValueError(f"{field_}: expected {what} names, got {name!r}")
            object.__setattr__(self, field_, tuple(sorted(set(hold))))
        if isinstance(self.marker_noise, Mapping):
            object.__setattr__(self, "marker_noise", tuple(sorted(self.marker_noise.items())))
        lock = self.lock
        if isinstance(lock, Mapping):
            lock = tuple(sorted(lock.items()))
        elif isinstance(lock, str):
            lock = ((lock, 0.0),)
        else:
            lock = tuple(sorted((x, 0.0) if isinstance(x, str) else tuple(x) for x in lock))
        object.__setattr__(self, "lock", lock)
        try:
            lateral = tuple((str(j), str(mk), d) for j, mk, d in self.lateral_markers)
        except (TypeError, ValueError):
            raise ValueError(f"lateral_markers: expected (joint, marker, distance in m) triples, got "
                             f"{self.lateral_markers!r}") from None
        object.__setattr__(self, "lateral_markers", lateral)
        for item in self.lock:
            if len(item) != 2 or not isinstance(item[0], str):
                raise ValueError(f"lock: expected DoF names or (DoF, angle) pairs, got {item!r}")
            v = item[1]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"lock: {item[0]}: the angle must be a number in radians, got {v!r}")
        for label, v in self.marker_noise:
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0 and math.isfinite(v)):
                raise ValueError(f"marker_noise: {label}: must be a positive noise SD in metres, got {v!r}")
        bad = [g for g in self.free if g not in GROUPS]
        if bad:
            raise ValueError(f"free: unknown parameter group(s) {', '.join(bad)}; choose from {', '.join(GROUPS)}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss: '{self.loss}' is not one of {', '.join(LOSSES)}")
        _positive("noise", self.noise)
        _positive("loss_scale", self.loss_scale)
        _positive("memory_mb", self.memory_mb)
        for name in ("marker", "centre", "axis", "scale", "held_centre", "placeholder"):
            v = getattr(self.priors, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"priors.{name}: must be a positive standard deviation, got {v!r}")
        for joint, marker, d in self.lateral_markers:
            if not (isinstance(d, (int, float)) and not isinstance(d, bool) and d > 0 and math.isfinite(d)):
                raise ValueError(f"lateral_markers: {joint}/{marker}: the distance must be a positive length "
                                 f"in metres, got {d!r}")
        for name in ("symmetry_scale", "symmetry_centre", "width", "on_axis", "pair_axis", "knee_landmark",
                     "ankle_landmark", "joint_marker", "size"):
            v = getattr(self.priors, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and v >= 0 and math.isfinite(v)):
                raise ValueError(f"priors.{name}: must be 0 (off) or a positive standard deviation, got {v!r}")


@dataclass(frozen=True)
class SolverOptions:
    """When Levenberg–Marquardt stops, and how it steps (the meanings of Settings' fields of the same names)."""

    max_iterations: int = 100
    ftol: float = 1e-6  # stop when the relative cost decrease of a step falls below this (as Ceres)
    atol: float = 0.5  # ... or a step lowers the cost by less than this: χ² by less than 1, its one-sigma level
    xtol: float = 1e-8  # ... or the step is smaller than xtol * (|x| + xtol)
    gtol: float = 1e-10  # ... or the largest gradient entry is below this
    geodesic: bool = True  # geodesic acceleration of the steps (follows curved valleys; least squares only)

    def __post_init__(self) -> None:
        for name in ("ftol", "atol", "xtol", "gtol"):
            _positive(name, getattr(self, name))
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations: must be a whole number >= 1, got {self.max_iterations!r}")
