"""Typed records a calibration hands to its report and its user: a calibrated quantity's change and
whether the trial identified it, notes on coordinates, and progress messages.

The report and the command line read their fields; their text (`name`, `note`, `text()`, `str()`)
is what the user reads, worded as before.
"""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

GROUPS = ("scale", "centre", "axis", "marker")  # the parameter blocks a ParameterChange belongs to


@dataclass(frozen=True)
class JointCentreMarker:
    """A marker the base model puts at a joint centre (calibrate.problem.priors.joint_centre_markers): a point
    the lab computed there (OpenSim's R_HJC at the femur's origin), not skin, so the calibration keeps its
    offset from the centre within Priors.joint_marker and the trial's positions of it place the centre."""

    marker: str
    joint: str
    offset: float  # m: its distance from the joint centre in the subject
    base_offset: float  # m: the same in the base model

    def to_json(self) -> dict:
        return {"marker": self.marker, "joint": self.joint, "offset_mm": 1e3 * self.offset,
                "base_offset_mm": 1e3 * self.base_offset}


class Identified(enum.Enum):
    """How far a trial pinned a calibrated quantity."""

    YES = "identified"  # the data fix it (its posterior SD well below its prior's)
    FIXED = "not free"  # not calibrated: kept at its value (counts as identified)
    ACROSS_AXIS = "across the axis only"  # a hinge centre: across its axis by the data, along it by the prior
    NO = "not identified"  # the prior holds it
    UNSEEN = "unseen"  # no marker seen on or below its segment: held at the base model's

    @property
    def identified(self) -> bool:
        return self in (Identified.YES, Identified.FIXED)


@dataclass(frozen=True)
class ParameterChange:
    """One calibrated quantity against the base model, with its posterior uncertainty."""

    group: str  # the parameter block: 'scale', 'centre', 'axis' or 'marker'
    item: str  # the segment (scale), joint (centre), DoF (axis) or marker it belongs to
    base: np.ndarray  # base model value (m for positions at base scale, unit vector, scale factor)
    value: np.ndarray  # calibrated value (positions at the subject's scale)
    change: float  # |value − base|: mm for positions, degrees for axes, fraction for scales
    std: np.ndarray  # posterior std per coordinate (mm / deg / fraction); NaN when not free
    status: Identified  # whether the trial identified it (or the prior holds it, and how)
    note: str = ""  # why not identified, in words ('' when identified)
    prior_ratio: float = float("nan")  # worst-direction posterior std / prior-only std (0: data alone, 1: prior alone)
    # Further from the base model's than its prior allows (calibration.identifiability: beyond FAR_FROM_PRIOR prior
    # SDs): not identified, a trade the data do not separate carried it there; identified, skin that moves with the
    # joints can (a centre, an axis).  Not to be trusted either way.
    unreliable: bool = False
    # A position's distance (mm) from the base model's at the subject's scale (its segment's scale times the base
    # model's offset): the change its scaling does not explain, which its prior counts; NaN for axes and scales.
    beyond_scale: float = float("nan")

    @property
    def name(self) -> str:
        """e.g. 'centre[knee_r]', 'axis[knee_r]', 'marker[RKNE]', 'scale[femur_r]' (the report's names)."""
        return f"{self.group}[{self.item}]"

    @property
    def identified(self) -> bool:
        """False: the trial could not pin it and its prior holds it."""
        return self.status.identified


STILL_RATIO = 3.0  # a coordinate whose spread over frames is below this many per-frame SDs is noted (still_notes)


@dataclass(frozen=True)
class StillNote:
    """A coordinate that moved no more than one frame's markers fix it (calibration.still_coordinates)."""

    coordinate: str  # DoF name
    spread: float  # rad: its SD over the frames
    per_frame: float  # rad: the SD with which one frame's markers fix it
    axis_held: bool  # its hinge axis was held at the base model's
    bare: str = ""  # the segment without markers beside its joint (the talus), across which it trades with the next
    neighbours: tuple[str, ...] = ()  # the coordinates of the other joints at `bare` (subtalar beside the ankle)
    ball: str = ""  # the ball joint it is one rotation of (hip_l for hip_l_adduction), if it is

    def text(self) -> str:
        if self.ball:
            # A ball joint has no axis to hold, and a walk's trunk rotation (Rajagopal's lumbar_rotation, 4.3 deg SD
            # in its walk, one frame fixing it to 1.5) is no rotation to lock: the note says what the trials show,
            # without that advice.
            return (f"{self.coordinate}: turned {math.degrees(self.spread):.1f} deg SD over the frames, under "
                    f"{STILL_RATIO:g} times what one frame's markers fix ({math.degrees(self.per_frame):.1f} deg): the "
                    f"trials show little of this rotation of "
                    f"{self.ball}, so its centre rests on its other rotations and the segment frame's zero about it "
                    f"on the priors (--lock {self.coordinate} holds it, if the subject kept it still)")
        if self.bare:
            # An ankle that turns 15 deg in a walk is no still joint: the markers cannot tell its turn from its
            # neighbour's across the markerless segment, so one frame fixes it only loosely.
            seen = (f"{self.coordinate}: one frame's markers fix it only to {math.degrees(self.per_frame):.1f} deg "
                    f"(its joint and the next trade off across {self.bare}, which carries no markers the trials show), "
                    f"and it moved no more than that allows (SD over frames {math.degrees(self.spread):.1f} deg): the "
                    f"trial does not separate its motion from its neighbour's, so ")
        else:
            seen = (f"{self.coordinate}: moved no more than the markers fix it in a frame (SD over frames "
                    f"{math.degrees(self.spread):.1f} deg, one frame's {math.degrees(self.per_frame):.1f} deg): the "
                    f"trial does not show this joint moving, so ")
        if self.bare and self.neighbours:
            held = "its axis was held at the base model's" if self.axis_held else "its axis is not found"
            pair = " or ".join((self.coordinate, *self.neighbours))
            return seen + (f"{held}; if one of {pair} hardly moved (a subtalar joint in a walk), lock that one "
                           f"(--lock NAME, or [lock_deg] in the config), as OpenSim's gait pipelines do: the other is "
                           f"then found")
        if self.axis_held:
            return seen + (f"its axis was held at the base model's and its angle's zero is not found; if it did not "
                           f"move at all, hold the angle too (--lock {self.coordinate}, or [lock_deg] in the config)")
        return seen + (f"its axis and zero are not found; if it hardly moved, hold it (--lock {self.coordinate}, or "
                       f"[lock_deg] in the config)")


@dataclass(frozen=True)
class TradingLock:
    """A hinge calibrate locked because the trials cannot separate its turn from a neighbour's across a segment
    without markers the trials show (calibration.identifiability.trading_locks; PipelineOptions.auto_hold)."""

    coordinate: str  # DoF name
    value: float  # rad: where it is held in every frame
    bare: str  # the segment without seen markers between the two joints (the talus)
    neighbours: tuple[str, ...]  # the other joints' coordinates at `bare` (the ankle beside the subtalar)
    spread: float  # rad: its SD over the frames before the lock
    per_frame: float  # rad: the SD with which one frame's markers fixed it
    neighbour_per_frame: tuple[float, ...]  # rad: the same for each of `neighbours`
    # rad: the pair's axes carried this far from the base model's by the trade, when that decided the lock (the
    # per-frame SDs are then the start's geometry's); 0 when the still test did
    turned: float = 0.0

    def text(self) -> str:
        fix = ", ".join(f"{n} to {math.degrees(v):.1f}" for n, v in zip(self.neighbours, self.neighbour_per_frame,
                                                                      strict=True))
        pair = " and ".join(self.neighbours)
        head = (f"{self.coordinate} at {math.degrees(self.value):g} deg: its turn and {pair}'s trade across "
                f"{self.bare}, which carries no markers the trials show")
        tail = ("the less-seen one is held, as OpenSim's gait models hold the subtalar, and the other found "
                "(--no-auto-hold leaves it free; --lock sets your own)")
        if self.turned:
            return (f"{head}, and the fit carried their axes {math.degrees(self.turned):.0f} deg from the base "
                    f"model's (the trade, not the data): the trials cannot say which of them turns, so the one "
                    f"beyond {self.bare} (of joints on one side of it, the less-seen) is held, as OpenSim's gait "
                    "models hold the subtalar, and the other found "
                    f"(at the start's geometry one frame's markers fixed it to {math.degrees(self.per_frame):.1f} "
                    f"deg, {fix}; --no-auto-hold leaves it free; --lock sets your own)")
        return (f"{head}; one frame's markers fix it only to {math.degrees(self.per_frame):.1f} deg ({fix}) and it "
                f"moved no more than that (SD over frames {math.degrees(self.spread):.1f} deg), so the trials cannot "
                f"separate the two: {tail}")


@dataclass(frozen=True)
class LimitNote:
    """A coordinate the fit drove beyond the base model's joint limits (calibration.limit_notes)."""

    coordinate: str  # DoF name
    fraction: float  # of the frames beyond the limits
    worst: float  # rad: furthest beyond them

    def text(self) -> str:
        return (f"{self.coordinate}: beyond the base model's joint limits in {100 * self.fraction:.0f} % of frames "
                f"(by up to {math.degrees(self.worst):.0f} deg): the markers may not resolve this coordinate; if "
                f"the joint hardly moved, hold it (--lock {self.coordinate}, or [lock_deg] in the config)")


@dataclass(frozen=True)
class ZeroNote:
    """Two free hinges across a segment without markers the trials show (an ankle and a subtalar across the talus),
    where no neutral trial sets their angles' zero (calibration.identifiability.zero_notes): the trials are fitted as
    well wherever the foot's standing orientation is shared between the two, so the priors, and where the solve stops,
    decide it (AddBiomechanics' Expert1, the same static with each of 25 trials: its ankle angles 9 deg SD apart)."""

    coordinate: str  # DoF name: the joint into the bare segment (the ankle)
    bare: str  # the segment without seen markers (the talus)
    neighbours: tuple[str, ...]  # the other joints' coordinates there (the subtalar)
    beyond: str  # the segment the neighbours turn (the calcaneus), whose orientation the two share
    still: int = 0  # the first still trial, numbered from 1 as --neutral takes it; 0: none

    def text(self) -> str:
        pair = " and ".join((self.coordinate, *self.neighbours))
        fix = (f"--neutral {self.still} takes it from trial {self.still}, the still one (its angles zero on average)"
               if self.still else "a static trial with --neutral sets it")
        return (f"{pair}: their angles' zero rests on the priors, not on the markers ({self.bare} between them carries "
                f"none the trials show, and the trials fit as well however {self.beyond}'s orientation is shared "
                f"between them; AddBiomechanics' Expert1: one static's ankle angles 9 deg SD apart over 25 "
                f"calibrations): {fix}, or lock one of them (--lock NAME)")


CoordinateNote = StillNote | LimitNote | ZeroNote


@dataclass(frozen=True)
class Progress:
    """One progress message of a calibration: its stage ('markers', 'seed', 'build', 'start', 'noise',
    'solve') and what happens; str() is the line the user reads ('stage: text')."""

    stage: str
    text: str
    iteration: int | None = None  # a solver iteration's line (subsample or single solve): its number
    long: bool = False  # announces a step that takes long (C compilation), before it starts

    def __str__(self) -> str:
        return f"{self.stage}: {self.text}" if self.stage else self.text

    @classmethod
    def of(cls, message: str | Progress) -> Progress:
        """The record of a message given as text ('stage: text', as Problem and the solver's callers
        still word theirs)."""
        if isinstance(message, Progress):
            return message
        stage, sep, text = message.partition(": ")
        if not sep:
            return cls("", message)
        it = text.split()[1] if text.startswith("iteration ") else None
        return cls(stage, text, int(it) if it is not None and it.isdigit() else None,
                   long=stage == "build" and text.startswith("compiling"))


class Countdown:
    """Progress of a long step whose share done is known (frames posed, chunks passed): one message
    at most every `every` seconds once a second has passed, with the time left at the rate since the first share
    was told (what comes before it — a trial's kinematics built, its damaged positions sought — is not the rate:
    `calibrate ik` on a 1424-frame trial said "about 16 s left" after its first second, and took 2 s)."""

    def __init__(self, say: Callable[[Progress], None], stage: str, text: str, every: float = 1.0):
        self.say, self.stage, self.text, self.every = say, stage, text, every
        self.t0 = self.last = time.perf_counter()
        self.first: tuple[float, float] | None = None  # (time, share) of the first share told

    def __call__(self, done: float) -> None:
        now = time.perf_counter()
        if self.first is None:
            self.first = (now, done)
        if now - self.last < self.every or now - self.t0 < 1.0 or not 0.0 < done < 1.0:
            return
        t1, d1 = self.first
        if done <= d1:
            return
        self.last = now
        left = (now - t1) * (1.0 - done) / (done - d1)
        self.say(Progress(self.stage, f"{self.text} {100 * done:.0f} % (about {left:.0f} s left)"))


class IterationClock:
    """Progress of a Levenberg–Marquardt run: each accepted iteration's line with its time and, once the
    cost's decreases shrink geometrically (the geometric mean ratio r of the last few below 0.9), how many
    more iterations and seconds the tolerances allow (the decrease falls below atol, or below ftol of the
    cost, after log(threshold/Δ)/log(r) more)."""

    def __init__(self, say: Callable[[Progress], None], label: str, atol: float, ftol: float):
        self.say, self.label, self.atol, self.ftol = say, label, atol, ftol
        self.t0 = self.last = time.perf_counter()
        self.costs: list[float] = []

    def __call__(self, iteration: int, cost: float, lam: float) -> None:
        now = time.perf_counter()
        took, self.last = now - self.last, now
        self.costs.append(cost)
        line = f"{self.label}iteration {iteration:3d}  cost {cost:.6e}  lambda {lam:.1e}  ({took:.1f} s)"
        d = -np.diff(self.costs[-5:])  # the last (up to) four decreases
        threshold = max(self.atol, self.ftol * cost)
        if d.size >= 2 and np.all(d > 0) and d[-1] >= threshold:
            rate = float(np.exp(np.mean(np.log(d[1:] / d[:-1]))))  # their geometric mean ratio
            if rate < 0.9:
                more = math.ceil(math.log(threshold / d[-1]) / math.log(rate))
                per = (now - self.t0) / len(self.costs)
                line += f"; about {more} more, {more * per:.0f} s"
        self.say(Progress.of(f"solve: {line}"))
