"""What is calibrated and how: Settings, the user's one flat set of options (parameter groups, noise, loss,
priors, locks, held axes, the solver's tolerances, the pipeline's switches), and its typed views for the parts
that read them: Settings.problem (ProblemOptions: the least-squares problem), Settings.solver (SolverOptions:
Levenberg–Marquardt) and Settings.pipeline (PipelineOptions: calibrate()).  Units: metres, radians."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import TypeVar

from ..calibration.options import PipelineOptions
from ..model.blocks import GROUPS
from .options import NOISE_DEFAULT, Priors, ProblemOptions, SolverOptions

__all__ = ["Priors", "Settings"]  # Priors: defined in calibrate.problem.options, imported from here too


T = TypeVar("T")


def _view(cls: type[T], settings: Settings, **resolved: object) -> T:
    """An instance of the options dataclass `cls` with the fields of the same names taken from `settings`."""
    return cls(**{f.name: resolved.get(f.name, getattr(settings, f.name)) for f in fields(cls)})


@dataclass(frozen=True)
class Settings:
    """What is calibrated and how, as the user states it (Python, a settings file, the command line).  Units:
    metres, radians.  Each part of calibrate reads its own view: `problem`, `solver`, `pipeline`."""

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
    memory_mb: float = 200.0  # MB of the frames' normal-equation blocks held at once; longer trials go chunk by chunk
    new_markers: bool = True  # place trial markers the model does not know on segments (by rigidity, else the
    # base model's poses: calibrate.calibration.hosts) and fit them
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
    # axis, and left free the axis drifts far from the base model's by fitting noise.  So is an axis the fit carried
    # beyond 3 prior SDs where the trials turn its joint through less than 20 deg (skin's turn of the segments
    # would place it: calibration.identifiability.NARROW_TURN), and a ball joint's centre carried beyond 3 prior SDs
    # where the trials turn every angle of it less than 20 deg (Calibration.narrow_centres).  When every trial is
    # still (a static alone), the centres of the ball joints with a chain below them (hips, shoulders, lumbar) that no
    # pair of markers across them shows turning are held too, at the base model's offset from their parent segments'
    # markers (as hold_centres; Calibration.still_centres).
    auto_hold: bool = True
    # Where the segment frames end, in which the joint angles are read (calibrate.calibration.gauge): "markers",
    # turned to where each segment's markers put them against the base model's (the frames a lab's model defines
    # by its markers, as OpenSim's marker placer does), or "priors", where the priors hold the geometry least (the
    # gauge the solve runs in).  None (default): "markers" for a model read from an OpenSim file, else "priors".
    segment_frames: str | None = None
    # Segments whose geometry is held at the base model's: their scale, the joint centres and markers
    # expressed in them, the axes of the joints into them.  calibrate holds the segments with no seen
    # marker on or below them (calibrate.model.resolve): nothing in the data reaches their parameters, and
    # left free only the priors' couplings (e.g. left/right symmetry) would move them.
    hold_segments: tuple[str, ...] = ()
    # Joints whose centre keeps the base model's place against the markers of the segment it is expressed in (its
    # offset from their centroid, at the size of their own layout; Priors.held_centre, 0.1 mm): a joint the trials
    # barely turn (a walk's lumbar, 1-6 deg SD) places its centre by a lever of a few degrees, and skin moving with the
    # arms carries it tens of mm (Rajagopal2016's back: 77-100 mm from the scaled model).  Where that segment shows
    # fewer than three markers, the centre is held in the segment's frame.
    hold_centres: tuple[str, ...] = ()
    # A hinge centre's distance along its axis from the lateral marker beside it (m), as the lab measured
    # it: ((joint, marker, distance), ...).  () (default): from the trials' subject measurements where they
    # carry them (Plug-in Gait's knee and ankle widths: half the width plus the marker's radius;
    # calibrate.io.measurements); priors.width = 0 leaves them unused.
    lateral_markers: tuple[tuple[str, str, float], ...] = ()
    # Learn each marker's noise SD from the trial's residuals (a robust scale, iterated with the solve;
    # calibrate.calibration.noise.learned_noise) instead of taking `noise` for all.  None (default): learn
    # unless `noise` was set away from NOISE_DEFAULT; markers named in `marker_noise` keep their value.
    learn_noise: bool | None = None
    # Run the start's parts that hold the GIL (the second candidate of the start's race, every second
    # trial's start poses) in a forked process on the other core (Linux, two or more cores;
    # calibrate.solve.ahead; the race's candidate, work on a guess, only when a core is idle at the time).  The
    # results are the same bits either way; off, they run one after another here (e.g. where the cores are busy
    # already, as in a batch's worker processes).
    ahead: bool = True
    # What a still trial (a static: one pose repeated, its errors with it) counts as, in frames in all, beside a
    # trial that moves (calibrate.calibration.pipeline._still_lengths); 0 (default): every frame once.  16 fitted
    # the walks' held-out frames 33-53 % better on the three real recordings (docs/benchmarks.md).
    still_weight: float = 0.0
    # Leave out a still trial's positions of the markers that sit elsewhere on their segment there than in the
    # moving trials (a slipped thigh cluster, an acromion marker lifted with the arms, a marker put back after
    # the static; calibrate.calibration.moved): the model keeps the moving trials' place, and says which.
    # Off by default: on the three real recordings the walks' held-out frames fit 35-45 % better, but the
    # calibration's own frames better still (pig_walk's held-out ratio 1.32x, past bench_real's 1.2x target;
    # docs/benchmarks.md).
    moved_markers: bool = False
    # Leave out a still trial's markers beyond a joint it holds where the moving trials never go (the arms out in
    # a static, at the sides in the walk: a shoulder without its blade cannot be both; calibrate.calibration.
    # far_joints), and say which.  Rajagopal2016's left elbow otherwise ends folded to 164 deg.
    far_joints: bool = True
    # Place the hip centres by Harrington's regression from the pelvis markers (calibrate.calibration.regression:
    # a virtual marker at each hip, kept there as a joint-centre marker), as gait labs do where no functional
    # trial places them: a walk does not (docs/benchmarks.md, "Hip centres from a walk").  "auto": calibrated without
    # it first, and again with it where that leaves a hip implausible (further than REGRESSION_FAR from the
    # regression, or the hips wider apart than HIP_WIDTH_FAR times the ASIS markers, where the trials' motion does
    # not place them; wider apart than the ASIS markers, wherever: calibrate.calibration.regression.HipMotion
    # .implausible).  "outside" (the default): the same, only where the hips end wider apart than the ASIS markers
    # or closer together than half their width (HipMotion.nowhere: outside the pelvis or on its midline, where no hip
    # is).  False: never.
    hip_regression: bool | str = "outside"

    @property
    def problem(self) -> ProblemOptions:
        """The options of the least-squares problem among these settings (calibrate.problem.problem.Problem)."""
        return _view(ProblemOptions, self)

    @property
    def solver(self) -> SolverOptions:
        """The options of the Levenberg–Marquardt solver among these settings (calibrate.solve.lm)."""
        return _view(SolverOptions, self)

    @property
    def pipeline(self) -> PipelineOptions:
        """The options of the pipeline among these settings (calibrate.calibration.pipeline), whether the
        noise is learnt decided (learns_noise)."""
        return _view(PipelineOptions, self, learn_noise=self.learns_noise)

    @property
    def learns_noise(self) -> bool:
        """Whether calibrate learns the markers' noise SDs from the data (see `learn_noise`)."""
        return self.noise == NOISE_DEFAULT if self.learn_noise is None else bool(self.learn_noise)

    def __post_init__(self) -> None:
        # Each view normalises (dicts and single names to sorted tuples) and checks its own fields.
        problem = _view(ProblemOptions, self)
        for name in ("marker_noise", "lock", "hold_axes", "hold_centres", "lateral_markers"):
            object.__setattr__(self, name, getattr(problem, name))
        _view(SolverOptions, self)
        if self.learn_noise is not None and not isinstance(self.learn_noise, bool):
            raise ValueError(f"learn_noise: must be true, false or None (auto), got {self.learn_noise!r}")
        _view(PipelineOptions, self, learn_noise=self.learns_noise)
