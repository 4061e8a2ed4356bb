"""What is calibrated and how: Settings (parameter groups, noise, loss, priors, locks, held axes, the
pipeline's switches) and the Priors' standard deviations.  Units: metres, radians."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from ..model.blocks import GROUPS
from .options import SolverOptions

LOSSES = ("linear", "huber", "cauchy")


NOISE_DEFAULT = 0.001  # m: Settings.noise unless given (then learnt from the data: Settings.learn_noise)


@dataclass(frozen=True)
class Priors:
    """Standard deviations of the priors that pull p towards the base model."""

    marker: float = 0.02  # m: how far a subject's marker may sit from the base model's place
    centre: float = 0.02  # m: same for a joint centre
    axis: float = math.radians(10.0)  # rad: tilt of a hinge axis
    scale: float = 0.25  # fraction: segment scale factor about 1
    # Left/right symmetry (segments and joints named *_l / *_r; 0: off): SD of the difference between
    # a left segment's scale factor and its right partner's (fraction), and between a left joint centre
    # and its right partner's mirrored through the sagittal plane (m, at the subject's scale), each
    # counted relative to the base model's own asymmetry.  Soft-tissue artefact pulls the two sides
    # apart by different amounts; a subject's bones are symmetric to a few per cent.
    symmetry_scale: float = 0.05
    symmetry_centre: float = 0.02


@dataclass(frozen=True)
class Settings:
    """What is calibrated and how.  Units: metres, radians."""

    free: tuple[str, ...] = GROUPS  # parameter groups the solve may change
    noise: float = NOISE_DEFAULT  # m: marker noise SD (weights the marker residuals; the start when learnt)
    loss: str = "linear"  # 'linear', 'huber' or 'cauchy'
    loss_scale: float = 3.0  # in units of `noise`: residuals beyond it count less (robust losses)
    priors: Priors = field(default_factory=Priors)
    # The solver's options (calibrate.problem.options.SolverOptions; `solver` gives them to levenberg_marquardt):
    max_iterations: int = 100
    ftol: float = 1e-6  # stop when the relative cost decrease of a step falls below this (as Ceres)
    atol: float = 0.5  # ... or a step lowers the cost by less than this: χ² by less than 1, its one-sigma level
    xtol: float = 1e-8  # ... or the step is smaller than xtol * (|x| + xtol)
    gtol: float = 1e-10  # ... or the largest gradient entry is below this
    seed: bool = True  # start from MTB joint centres (else from the base model)
    compile: bool = True  # compile the per-frame function with the C compiler, if there is one
    new_markers: bool = True  # place trial markers the model does not know on segments (by rigidity) and fit them
    outliers: float = 6.0  # reject a marker in a frame whose error exceeds this many noise SDs (0: keep all)
    geodesic: bool = True  # geodesic acceleration of the LM steps (follows curved valleys; calibrate.solve.lm)
    # Per-marker noise SD (m) where a marker is noisier or steadier than `noise`, e.g. wand markers
    # on soft tissue: ((label, SD), ...) or a dict.  An OpenSim marker weight w is the SD noise/sqrt(w).
    marker_noise: tuple[tuple[str, float], ...] = ()
    # Coordinates held at a value (rad) in every frame, as OpenSim's locked coordinates: DoFs the
    # marker set cannot resolve (e.g. the subtalar joint under a two-marker foot).  ((DoF, angle), ...),
    # a dict, or DoF names (held at 0).  A locked hinge's axis is not calibrated.
    lock: tuple[tuple[str, float], ...] = ()
    # Hinge and universal DoFs whose axis keeps the base model's direction (their angles stay free).
    hold_axes: tuple[str, ...] = ()
    # Hold, as above, the axis of every coordinate the trial does not show moving (calibrate decides
    # after the solve on the subsample, and says so): a joint that hardly moves cannot place its
    # axis, and left free the axis drifts far from the base model's by fitting noise.
    auto_hold: bool = True
    # Segments whose geometry is held at the base model's: their scale, the joint centres and markers
    # expressed in them, the axes of the joints into them.  calibrate holds the segments with no seen
    # marker on or below them (calibrate.model.resolve): nothing in the data reaches their parameters, and
    # left free only the priors' couplings (e.g. left/right symmetry) would move them.
    hold_segments: tuple[str, ...] = ()
    # Learn each marker's noise SD from the trial's residuals (a robust scale, iterated with the solve;
    # calibrate.calibration.noise.learned_noise) instead of taking `noise` for all.  None (default): learn
    # unless `noise` was set away from NOISE_DEFAULT; markers named in `marker_noise` keep their value.
    learn_noise: bool | None = None

    @property
    def solver(self) -> SolverOptions:
        """The options of the Levenberg–Marquardt solver among these settings (calibrate.solve.lm)."""
        return SolverOptions(self.max_iterations, self.ftol, self.atol, self.xtol, self.gtol, self.geodesic)

    @property
    def learns_noise(self) -> bool:
        """Whether calibrate learns the markers' noise SDs from the data (see `learn_noise`)."""
        return self.noise == NOISE_DEFAULT if self.learn_noise is None else bool(self.learn_noise)

    def __post_init__(self) -> None:
        hold = (self.hold_axes,) if isinstance(self.hold_axes, str) else self.hold_axes
        object.__setattr__(self, "hold_axes", tuple(sorted(set(hold))))
        for name in self.hold_axes:
            if not isinstance(name, str):
                raise ValueError(f"hold_axes: expected DoF names, got {name!r}")
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
        for name in ("noise", "loss_scale", "ftol", "atol", "xtol", "gtol"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        for name in ("marker", "centre", "axis", "scale"):
            v = getattr(self.priors, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"priors.{name}: must be a positive standard deviation, got {v!r}")
        for name in ("symmetry_scale", "symmetry_centre"):
            v = getattr(self.priors, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and v >= 0 and math.isfinite(v)):
                raise ValueError(f"priors.{name}: must be 0 (off) or a positive standard deviation, got {v!r}")
        if self.learn_noise is not None and not isinstance(self.learn_noise, bool):
            raise ValueError(f"learn_noise: must be true, false or None (auto), got {self.learn_noise!r}")
        if not (isinstance(self.outliers, (int, float)) and self.outliers >= 0 and math.isfinite(self.outliers)):
            raise ValueError(f"outliers: must be 0 (off) or a positive number of noise SDs, got {self.outliers!r}")
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations: must be a whole number >= 1, got {self.max_iterations!r}")
