"""Subject calibration from one trial: seed, start, global solve, result (seed 003).

    calibrate(model, trial, settings)  ->  Calibration
      1. seed    MTB joint centres (calibrate.seed.joints) -> segment scale factors, joint centres
                 and hinge axes in segment frames; the base model where the seed fails.
      2. start   frame-wise inverse kinematics with the seeded geometry on key frames (every
                 `stride`-th, warm-started key frame to key frame), interpolated between
                 them, then refined for all frames at once with the geometry held.
      3. solve   one Levenberg–Marquardt over every frame's coordinates and the free
                 parameters (calibrate.problem.problem, calibrate.solve.lm).
      4. result  parameters, motion, marker errors, posterior standard deviations and the
                 parameters the trial could not identify (held by their priors).
"""

from __future__ import annotations

import math
import time
import warnings
from collections import Counter
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from calibrate.calibration import regression
from calibrate.calibration.far_joints import FarJoint, far_joints, refit_beyond
from calibrate.calibration.gauge import align_gauge, align_markers, align_neutral
from calibrate.calibration.hosts import (
    AXIAL_SPREAD,
    NAMED_SEGMENTS,
    BasePoses,
    beyond_joints,
    centre_labels,
    centre_segments,
    cluster_hosts,
    described_labels,
    joint_hosts,
    kinematic_hosts,
    medial_host,
    named_kind,
    named_segments,
    past_joints,
    trial_exchanges,
)
from calibrate.calibration.identifiability import (
    FAR_FROM_PRIOR,
    NARROW_TURN,
    STILL_SAMPLE,
    coordinate_notes,
    coordinate_spreads,
    even_frames,
    joint_turns,
    length_differences,
    mirror_differences,
    parameter_changes,
    still_of,
    trading_locks,
    zero_notes,
)
from calibrate.calibration.moved import (
    ExchangedCluster,
    MovedMarker,
    PlacesApart,
    exchanged_after_solve,
    exchanged_clusters,
    marker_places,
    moved_markers,
    places_apart,
    relabel_columns,
    replaced,
    segment_axes,
)
from calibrate.calibration.noise import find_outliers, fixed_noise, leverage, relearn, tau_cap
from calibrate.calibration.plugin_gait import knee_axis_checks
from calibrate.calibration.regression import hip_joints, hip_motion, regression_hips
from calibrate.calibration.result import Calibration, NewMarker, Outlier, trial_spans
from calibrate.calibration.start import (
    COARSE_FRAMES,
    absolute,
    bridge,
    choose_start,
    frames_of,
    key_stride,
    spread_frames,
    spread_poses,
    stack_states,
    start_poses,
    subsample_weight,
    with_frames,
)
from calibrate.seed.joints import JointEstimates
from calibrate.seed.seeding import (
    MIN_FRAMES,
    ExchangedBack,
    Seed,
    episodes,
    exchanged_back,
    handedness,
    jumped_samples,
    seed_parameters,
    segment_distances,
    size_from_markers,
    without_broken,
)

from ..errors import CalibrateError
from ..io.labels import UNLABELLED, declared_segments, plug_in_gait_name
from ..io.measurements import (
    WIDTH_JOINTS,
    SubjectMeasurements,
    first_measurements,
    lateral_markers_of,
)
from ..io.motion import Motion
from ..io.trial import Trial
from ..model.blocks import FrameLayout
from ..model.kinematics import Kinematics, build_kinematics
from ..model.model import Model, Parameters, add_markers, hinge_axis
from ..model.urdf import mass_factor
from ..problem.gauge import MARKER_FRAMES
from ..problem.options import SolverOptions
from ..problem.priors import held_layout, joint_centre_markers, straddle
from ..problem.problem import LIMIT_MARGIN, Problem
from ..problem.settings import Settings
from ..problem.state import State
from ..seed.association import associate_to_model, exchanged_between, margin_hosts, misplaced_labels, split_reason
from ..seed.rigidity import distance_variance
from ..solve.ahead import run_ahead
from ..solve.chunks import frame_bytes
from ..solve.ik import FrameSolver, bridge_unplaced, bridge_unseen, marker_columns, refit_bridged
from ..solve.lm import Run, SolverSummary, covariance, levenberg_marquardt
from ..solve.memory import no_huge_pages
from .options import HIP_MODES, PipelineOptions
from .records import Countdown, IterationClock, JointCentreMarker, Progress, StillNote, TradingLock

MOVED_SAMPLE = 500  # frames of each trial the moved-marker test reads when it only names what it finds
MOVED_PASSES = 2  # looks for markers moved in a still trial (calibrate.calibration.moved), each then a subsample solve
HOLD_ROUNDS = 2  # rounds of holding still coordinates' axes (PipelineOptions.auto_hold), each a new subsample solve
NARROW_FAR = FAR_FROM_PRIOR  # prior SDs: "far" for NARROW_TURN, as for the report's unreliable axes
# Prior SDs: "far" for a centre's NARROW_TURN (_narrow_centres): as for the report's unreliable centres.  At 2 SDs
# pig_walk's lumbar centre (55 mm from the base model's at the subject's scale, not flagged) was held, and its marker
# RMS rose from 8.55 to 10.31 mm (docs/benchmarks.md).
NARROW_CENTRE_FAR = FAR_FROM_PRIOR
# rad: a far centre whose joint turns widely about one axis only is held where its shift lies within this of that
# axis, the direction no turn about it places (_narrow_centres): PiG_Motion-FlatFoot-Full's back on Rajagopal2016.osim,
# 75 mm, 37 deg from its 22 deg lumbar rotation's axis; shd01's, 192 mm, 80 deg from its lateral bending's.
ALONG_AXIS = math.radians(60.0)


OUTLIER_ROUNDS = 8  # rejection rounds (each takes at most one marker per frame)


SETTLE_PASSES = 2  # outlier tests, each then a solve (the second with the noise learnt at the first's solution)


# A marker whose positions the outlier test rejects REFIT_ERROR or more from its place, in REFIT_SHARE or more of the
# frames it is seen in in a trial (and REFIT_FRAMES or more), is calibrated again from the start without them: such a
# stretch (a marker fallen off that no test before the solve took) has carried the seed and the subsample's geometry
# into another minimum, which the solve on every frame does not leave once they are out (gait2392's R.Thigh.Rear on
# the floor for the walk's last 41 of 151 frames: rejected at the end, yet the hips 44-70 mm from the calibration
# with them unseen, whose 3 posterior SDs are 3.6 mm).  50 mm: Rajagopal's L.Heel lowered to the floor for the walk's
# last 45 frames, its foot standing, was rejected 70-105 mm off in 41 of them, too few of them at 0.1 m (hip_l 69 mm
# off); on 75 real calibrations no marker is rejected so even at 30 mm.
REFIT_ERROR = 0.05  # m
REFIT_SHARE = 0.1
REFIT_FRAMES = 10


# The first solve on every frame pauses once an accepted step lowers the cost by less than this many times the
# solver's atol (a χ² change of 10 at atol 0.5); the noise learnt again and the outlier test at its solution
# then change the problem by more (pig_walk: weights by up to 15 %, 40 positions rejected, the cost by 30), and
# the solve after them converges to the tolerance (if they change nothing, the paused solve goes on).
# Converging the first to it as well took pig_walk's first solve 16 steps where 9 reach this
# (docs/benchmarks.md).
FIRST_RUN_ATOL = 10.0


POSE_MISS = math.radians(0.5)  # a lab's static pose angle further than this from its value at the end is said
NOISE_ROUNDS = 3  # learn-and-solve rounds on the subsample (then once more on every frame)


# ---------------------------------------------------------------------- calibrate
def calibrate(model: Model, trials: Trial | Sequence[Trial], settings: Settings | None = None, *,
              marker_map: Mapping[str, Sequence[str]] | None = None, aliases: bool = True,
              kinematics: Kinematics | None = None, mass: float | None = None, neutral: int | None = None,
              pose: Mapping[str, float] | None = None,
              progress: Callable[[Progress], None] | None = None) -> Calibration:
    """Calibrate `model` to one trial or several trials of one subject: the subject's scales, joint
    centres, hinge axes and marker positions (shared by every trial), and every frame's
    coordinates, in one least-squares problem (module docstring).

    Trial labels are first renamed to the model's: by `marker_map` (model label -> trial labels,
    calibrate.io.labels.load_marker_map) and, with `aliases`, the common spellings of the same
    landmarks (R.ASIS, RASIS -> RASI; calibrate.io.labels).  Labels the model still does not know are
    placed on segments by rigidity, or failing that by their places' spread on the base model's poses
    (calibrate.calibration.hosts: a cluster on skin), and fitted like the model's markers (``Settings.new_markers``);
    those that fit no segment are left out and listed.
    `mass`: the subject's body mass (kg); the written model's segment masses (and inertias) are
    the base model's scaled to it, as OpenSim's Scale tool does (None: the base model's kept).
    `neutral`: index of the trial in which the subject stands in the model's neutral pose (a static
    trial): every segment frame that markers do not fix (see docs/calibration.md, gauges) is turned
    so that the joint angles of that trial are zero on average, as a lab's static calibration
    defines them (None: the frames sit where the priors put them).
    `pose`: the angles (coordinate -> rad) trial `neutral` holds, where the lab defines its static pose by a few
    coordinates rather than all at zero (its OpenSim Scale setup's coordinate tasks, which OpenSim's marker placer
    poses the model by: calibrate.io.osim_setup.static_pose): only the segment frames of those coordinates' joints
    are turned, each named angle to its value on average in that trial (which then need not be still); the data
    fit is unchanged.
    `progress` receives a Progress record (calibrate.calibration.records) per step (its stage and
    text; str() is the line to show).
    Raises CalibrateError with one line if the trials and model share too few markers or frames.
    """
    trials = (trials,) if isinstance(trials, Trial) else tuple(trials)
    mass_factor(model, mass)  # a bad mass fails now, not after the solve
    if not trials:
        raise CalibrateError("no trial given; pass at least one Trial")
    for t in trials:
        if not isinstance(t, Trial):
            raise CalibrateError(f"expected Trial objects (calibrate.read_trial), got {type(t).__name__}")
    settings = settings or Settings()
    if settings.hip_regression in HIP_MODES:
        return _hips_auto(model, trials, settings, dict(marker_map=marker_map, aliases=aliases,
                                                        kinematics=kinematics, mass=mass, neutral=neutral,
                                                        pose=pose, progress=progress))
    # The linear algebra here is many small blocks plus one Schur complement: one BLAS thread is
    # faster than several (which also fight CasADi's two evaluation threads for the cores).
    label_maps: tuple = ()
    declared = declared_segments(marker_map, model)  # the marker map's new labels by segment ([segments])
    if clash := [lab for lab in declared if lab in model.marker_names]:
        raise CalibrateError(f"{getattr(marker_map, 'source', None) or 'marker map'}: [segments] "
                             f"{declared[clash[0]]} lists {clash[0]!r}, which is a marker of {model.path.name}; "
                             "[segments] is for labels the model does not have: remove it there")
    if absent := [lab for lab in declared if not any(lab in t.labels for t in trials)]:
        from ..io.labels import MarkerMapWarning

        warnings.warn(f"{getattr(marker_map, 'source', None) or 'marker map'}: [segments] lists {len(absent)} label"
                      f"{'' if len(absent) == 1 else 's'} no trial shows ({', '.join(absent[:6])}"
                      f"{', ...' if len(absent) > 6 else ''}): check the spelling if the trials carry them",
                      MarkerMapWarning, stacklevel=2)
    if marker_map or aliases:
        from ..io.labels import map_labels

        mapped = [map_labels(t, model.marker_names, marker_map, aliases=aliases) for t in trials]
        trials = tuple(t for t, _ in mapped)
        label_maps = tuple(m for _, m in mapped)
    if settings.pipeline.hip_regression:  # a virtual marker at each hip, where Harrington's regression puts it
        model, trials, _ = regression_hips(model, trials)
        kinematics = None  # built for the model without them
    # A lab's joint centres written as markers (R_HJC: its software's hip centre) the model lacks: each a marker at
    # its joint's centre (the child segment's origin), which the joint-centre tie keeps there, so that the lab's
    # point places the centre as a base model carrying it does (Rajagopal's) -- not a skin marker placed by the
    # hosts' tests, 20 mm free.  Not the hips' under --hip-regression, whose points place them.
    if settings.pipeline.new_markers and settings.priors.joint_marker > 0 and "marker" in settings.free:
        skip = [j.name for j in hip_joints(model).values()] if settings.pipeline.hip_regression else ()
        if tied := centre_labels(model, [lab for t in trials for lab in t.labels], skip):
            model = add_markers(model, {lab: (j.child, np.zeros(3)) for lab, j in tied.items()})
            kinematics = None
            _announcer(progress)(Progress("markers", "a lab's joint centres: " + ", ".join(
                f"{lab} at {j.name}" for lab, j in tied.items()) + ", each tied to its joint's centre (by its name)"))
    # A model imported from OpenSim locks its locked coordinates (calibrate.io.osim), unless settings lock them,
    # and its segment frames end where its markers put them (Settings.segment_frames), unless settings say
    # otherwise; the OpenSim readers (50 ms of imports) are loaded only for such a model.
    given = settings.lock  # the user's locks (Settings.lock, --lock, an IK setup's tasks), checked against the ranges
    opensim = "<opensim" in model.text
    if opensim:
        from ..io.osim_info import with_gimbals, with_locked

        settings = with_gimbals(model, with_locked(model, settings))
    if settings.segment_frames is None:
        settings = replace(settings, segment_frames="markers" if opensim else "priors")
    known = set(model.marker_names).union(*(t.labels for t in trials))
    unknown = [label for label, _ in settings.marker_noise if label not in known]
    if unknown:
        raise CalibrateError(f"marker_noise: '{unknown[0]}' is neither a marker of {model.path.name} nor a trial "
                             f"label; use one of their labels ({', '.join(model.marker_names[:6])}, ...)")
    bad = [name for name, _ in settings.lock if name not in model.dof_names]
    if bad:
        raise CalibrateError(f"lock: '{bad[0]}' is not a coordinate of {model.path.name}; use one of its DoF names "
                             f"({', '.join(model.dof_names[:6])}, ...; see calibrate inspect)")
    for name, value in given:
        # A coordinate held outside the joint's range poses the segments where no subject can (--lock knee_r=500
        # ran to a femur 200 mm off and tibias 47 % apart, reported converged).
        d = model.dofs[model.dof_index(name)]  # every DoF turns (rad); a continuous one has no range
        if not d.lower - 1e-9 <= value <= d.upper + 1e-9:
            raise CalibrateError(f"lock: {name} at {np.degrees(value):g} deg is outside its range in "
                                 f"{model.path.name} ({np.degrees(d.lower):g} to {np.degrees(d.upper):g} deg); give a "
                                 f"value within it")
    axis_dofs = [d for j in model.joints if j.kind in ("hinge", "universal") for d in j.dofs]
    bad = [name for name in settings.hold_axes if name not in axis_dofs]
    if bad:
        raise CalibrateError(f"hold_axes: '{bad[0]}' is not a hinge or universal-joint coordinate of "
                             f"{model.path.name}; use one of {', '.join(axis_dofs[:6])}, ... (see calibrate inspect)")
    joints = [j.name for j in model.joints]
    bad = [name for name in settings.hold_centres if name not in joints]
    if bad:
        raise CalibrateError(f"hold_centres: '{bad[0]}' is not a joint of {model.path.name}; use one of "
                             f"{', '.join(joints[:6])}, ... (see calibrate inspect)")
    hinges = {j.name: j for j in model.joints if j.kind == "hinge"}
    for joint, marker, _ in settings.lateral_markers:
        if joint not in hinges:
            raise CalibrateError(f"lateral_markers: '{joint}' is not a hinge joint of {model.path.name}; use one of "
                                 f"{', '.join(list(hinges)[:6])}, ... (see calibrate inspect)")
        if marker not in model.segments[model.segment_index(hinges[joint].parent)].markers:
            raise CalibrateError(f"lateral_markers: '{marker}' is not a marker of {hinges[joint].parent}, the segment "
                                 f"{joint} hangs from; use one of its markers")
    if neutral is not None and not (isinstance(neutral, int) and 0 <= neutral < len(trials)):
        raise CalibrateError(f"neutral: {neutral!r} is not the index of one of the {len(trials)} trials "
                             f"(0 for the first)")
    if pose is not None:
        if neutral is None:
            raise CalibrateError("pose: the coordinates a trial holds need that trial: give neutral=K as well")
        bad = [name for name in pose if name not in model.dof_names]
        if bad:
            raise CalibrateError(f"pose: '{bad[0]}' is not a coordinate of {model.path.name}; use one of its DoF names "
                                 f"({', '.join(model.dof_names[:6])}, ...; see calibrate inspect)")
        pose = {name: float(v) for name, v in pose.items()}
    if neutral is not None and pose is None and (moves := relative_motion(trials[neutral], model)) >= STILL_MOTION:
        # Its joint angles made zero on average would turn every segment frame by a walk's mean pose.
        still = [i for i, t in enumerate(trials) if relative_motion(t, model) < STILL_MOTION]
        raise CalibrateError(f"neutral: trial {neutral + 1} ({trials[neutral].source or 'in memory'}) moves (markers "
                             f"on different segments change their distances by {1000 * moves:.1f} mm SD; a static "
                             "keeps them to 0.4-1.6 mm); the neutral trial is a static in the model's neutral pose: "
                             + (f"give trial {still[0] + 1} ({trials[still[0]].source or 'in memory'})" if still
                                else "record one, or leave --neutral out"))
    measured = first_measurements(trials)
    mass_from = None if mass is None else "given"
    if mass is None and measured is not None and measured.mass is not None:
        mass, mass_from = measured.mass, measured.source or "the trial's subject measurements"
    if not settings.lateral_markers and measured is not None:
        # The knees', ankles' and elbows' (WIDTH_JOINTS), beside movement trials and in statics alone.
        settings = replace(settings, lateral_markers=lateral_markers(model, measured))
    with threadpool_limits(limits=1, user_api="blas"), no_huge_pages():
        cal = _calibrate(model, trials, settings, kinematics, progress, neutral, pose, declared)
        if gone := refit_outliers(cal):
            first = sum(cal.times.values())
            names = sorted({o.marker for o in gone})
            _announcer(progress)(Progress(
                "solve", f"{len(gone)} positions of {', '.join(names)} rejected {1000 * REFIT_ERROR:.0f} mm or more "
                         f"from {'its' if len(names) == 1 else 'their'} place: calibrated again without them"))
            cal = _calibrate(model, trials, settings, kinematics, progress, neutral, pose, declared, gone=gone)
            cal = replace(cal, times={"first run": first, **cal.times})
    return replace(cal, label_maps=label_maps, mass=None if mass is None else float(mass), neutral=neutral,
                   mass_from=mass_from, measurements=measured)


#: Statics alone (every trial still): the geometry's basin found on this many evenly spaced frames, not
#: COARSE_FRAMES.  Their frames repeat one pose (the subsample is weighted to stand for them all): pig_walk's static
#: took half the time (9.8 -> 4.7 s, 160 -> 69 iterations), each centre's distance from Plug-in Gait's within 5 mm
#: of the 120-frame answer's, and the simulator's statics ended as near the truth or nearer on every subject
#: (docs/benchmarks.md, "A static alone: the ball centres held").
STILL_COARSE_FRAMES = 24


def refit_outliers(cal: Calibration) -> tuple[Outlier, ...]:
    """The outliers of `cal` to calibrate again without, from the start: of each trial and marker whose positions
    the solve's outlier test rejected REFIT_ERROR or more from its place number REFIT_FRAMES or more and REFIT_SHARE
    or more of the frames it is seen in there, those positions (none: a few spikes, which the solve has already let
    go; the positions left out before the start are out of the seed already)."""
    seen = np.isfinite(cal.residuals[..., 0])  # (F, markers): fitted, not rejected
    spans = trial_spans(cal.trials)
    far: dict[tuple[int, str], list[Outlier]] = {}
    for o in cal.outliers:
        if o.error >= REFIT_ERROR and not o.before:
            far.setdefault((o.trial, o.marker), []).append(o)
    gone: list[Outlier] = []
    for (i, marker), found in far.items():
        shown = int(seen[spans[i], cal.model.marker_index(marker)].sum()) + len(found)
        if len(found) >= max(REFIT_FRAMES, REFIT_SHARE * shown):
            gone += found
    return tuple(gone)


def population_widths(problem: Problem) -> tuple[str, ...]:
    """The hinges Problem.slide_centres places by the population's width (Priors.population_width): each knee, ankle
    and elbow (WIDTH_JOINTS) that it slides, whose Plug-in Gait lateral marker the trials show, whose measured width
    does not place it (Settings.lateral_markers, unless Priors.width is 0) and which no two markers straddling it
    place (Problem.pair_terms)."""
    m, st = problem.model, problem.settings
    if st.priors.population_width <= 0:
        return ()
    measured = {j for j, _, _ in st.lateral_markers} if st.priors.width > 0 else set()  # (width 0: not used)
    taken = measured | {m.joints[ji].name for ji, *_ in problem.pair_terms()}
    slid = {m.joints[ji].name for ji in problem.slid_hinges()}
    return tuple(j for j, mk in lateral_markers_of(m, WIDTH_JOINTS)
                 if j in slid and j not in taken and not problem.unseen[m.marker_index(mk)])


def lateral_markers(model: Model, measured: SubjectMeasurements, joints: Sequence[str] = WIDTH_JOINTS
                    ) -> tuple[tuple[str, str, float], ...]:
    """(joint, lateral marker, distance) for Settings.lateral_markers from a subject's measured widths: each
    hinge of `joints` in `model` (named knee_l, ankle_r, ... as in models/human.urdf) whose measured width
    is known and whose parent segment carries the Plug-in Gait lateral marker (LKNE, RANK, ...), at half the
    width plus the marker's radius."""
    return tuple((name, marker, d) for name, marker in lateral_markers_of(model, tuple(joints))
                 if (d := measured.lateral_distance(name)) is not None)


def _calibrate(model: Model, trials: tuple[Trial, ...], settings: Settings, kinematics: Kinematics | None,
               progress: Callable[[Progress], None] | None, neutral: int | None = None,
               pose: Mapping[str, float] | None = None, declared: Mapping[str, str] | None = None,
               gone: Sequence[Outlier] = ()) -> Calibration:
    """calibrate() on trials already checked; `gone`: marker positions (of an earlier run's outliers) left out from
    the start, with those the seeding's tests leave out."""
    say = _announcer(progress)
    declared = declared or {}
    run, solver = settings.pipeline, settings.solver  # the pipeline's and the solver's options (never changed here)
    times: dict[str, float] = {}
    where = ", ".join(t.source or "trial" for t in trials)
    if len(model.markers) == 0:
        raise CalibrateError(f"{model.path}: the model has no markers; add marker links (see docs/model-format.md)")
    known = set(model.marker_names)
    labels = list(dict.fromkeys(lab for t in trials for lab in t.labels))  # first trial's order first
    shared = [lab for lab in model.marker_names if lab in set(labels)]
    if len(shared) < 3:
        raise CalibrateError(f"{where}: only {len(shared)} of its labels match markers of {model.path.name} "
                             f"(model markers: {', '.join(model.marker_names[:6])}, ...); rename the labels "
                             f"(--markers map.toml) or use a model with this marker set"
                             + ("; trials of clusters alone (a CAST protocol's) calibrate beside a static that shows "
                                "the model's markers and the clusters, listed under their segments in the map's "
                                "[segments]" if not shared else ""))
    # Trials of clusters alone beside one with the model's landmarks (a CAST protocol's static and walks): posed, once
    # the trials with the model's markers have placed the clusters, by the clusters (_bare_trials).
    bare = _bare_trials(model, trials, declared)
    members = _members(model, declared)  # which segment each label rides on, the declared ones' too (their motion)
    t0 = time.perf_counter()
    # Moving trials that name a cluster's new labels otherwise than each other (a symmetric plate labelled the other way
    # round in some of them): read as the trial that agrees with the most others names them, before anything reads
    # the labels (hosts.trial_exchanges; pooled, the places of such labels spread over the trials and the host rule
    # left them out).
    early: list[ExchangedCluster] = []
    # The model's own markers likewise (a lab's OpenSim marker set: its placeholder clusters as new labels).
    unknown0 = ([lab for lab in labels if lab not in known and not UNLABELLED.fullmatch(lab)]
                if run.new_markers else [])
    matched = len(trials) > 1 and run.outliers > 0  # the trials' labels matched against each other
    if matched:
        # A mirror image of the model is refused first (not again below): read against the others, its segments'
        # labels would be "exchanged" (a mirrored simulated squat's with its own original: both thighs' markers read
        # back).
        _check_handedness(model, trials)
        moving0 = [i for i, t in enumerate(trials) if relative_motion(t, members) >= STILL_MOTION]
        early = trial_exchanges(model, trials, moving0, unknown0,
                                [i for i in range(len(trials)) if i not in moving0])
        for x in early:
            say(Progress("markers", x.text(trials[x.trial].source or f"trial {x.trial + 1}",
                                           trials[x.reference].source or f"trial {x.reference + 1}")))
        read = {i: {a: b for x in early if x.trial == i for a, b in zip(x.labels, x.read_as, strict=True)}
                for i in {x.trial for x in early}}
        trials = tuple(replace(t, labels=tuple(read[i].get(lab, lab) for lab in t.labels)) if i in read else t
                       for i, t in enumerate(trials))
    # A label exchanged for a whole trial (a knee marker named as the ankle's) bends the geometry to fit it, and
    # no frame's outlier test sees it: each trial's labels are checked against the model's segments by rigidity.
    # A marker at a joint centre (R_HJC, --hip-regression's) rides with both of its joint's segments: not judged.
    centred = {model.markers[t.marker].name for t in joint_centre_markers(model, model.parameters())}
    # Judged on trials that move: in a still one every label keeps its distance to every segment's markers, and
    # the test would weigh only their noise (Pose2Sim's crouching child: LShoulder "with the pelvis", 0.0 mm SD).
    # Nor on one whose markers on one segment move against each other nearly as much as across the joints (Pose2Sim's
    # augmented static: 21 mm across, 9 within; five labels named "with" an arm or a shank).
    # Judged without the samples that jump away and back or break their segment's distances (spikes, swapped
    # labels; as the seed leaves them out): one frame of a ghost a metre off set the SD of every distance of its
    # marker, so that a static read as moving (its still joints no longer held) and a correct label "moved with
    # another segment" (docs/benchmarks.md, "Ghost spikes").
    # So are the stretches where a marker jitters (seed.jitter: one marker given 100 mm of noise put a hip 240 mm off).
    # Two labels exchanged once and not back (to a trial's end) are exchanged back on the side the base model's
    # distances put the wrong way round (seeding.lone_exchanges): left out instead, a pelvis's LASI and RPSI over half
    # a walk left the pelvis two markers and put the left hip 161 mm off.
    backs: list[list[ExchangedBack]] = [[] for _ in trials]
    damage = [episodes(t, Countdown(say, "seed", "jumps (swapped labels, spikes) in every trajectory"), model, back)
              for t, back in zip(trials, backs, strict=True)] if run.outliers > 0 else None  # found once: left out of
    # the solve too (jumped)
    exchanged_back_ = tuple((i, x) for i, back in enumerate(backs) for x in back)
    if exchanged_back_:
        trials = tuple(exchanged_back(t, back) for t, back in zip(trials, backs, strict=True))
        for i, x in exchanged_back_:
            say(Progress("markers", f"{trials[i].source or f'trial {i + 1}'}: {x.text()}"))
    damaged = [d[0] for d in damage] if damage is not None else None
    judged = tuple(without_broken(model, t, e)[0] for t, e in zip(trials, damaged, strict=True)) \
        if damaged is not None else trials
    own_motion = [relative_motion(t, members) for t in judged] if run.outliers > 0 else []  # (none: nothing judged)
    misplaced = tuple((i, m) for i, (t, moves) in enumerate(zip(judged, own_motion, strict=False))
                      if moves >= STILL_MOTION and moves >= MISPLACED_MOTION * segment_jitter(t, model)
                      for m in misplaced_labels(model, [t], skip=centred, clean=False))
    # Two labels of one segment exchanged in one trial and not in another (a walk's heel and toe), or alike in every
    # trial: rigidity cannot see it; their distances to the markers near them can (between the trials, or against
    # the base model's).
    exchanged = exchanged_between(model, trials, skip=centred) if run.outliers > 0 else ()
    # Alike in every trial and unlike the base model, and the only such pair on its segment (a mirror pair's twin
    # reads alike): the lab's protocol puts each where the model has the other.  The labels stay; the base
    # model's places of the two are exchanged where the fit starts and where its priors hold them (_protocol_places).
    sole = Counter(x.segment for x in exchanged if x.against_model)
    # (Named against the model only where no two trials differ (association.exchanged_between): a trial the model
    # comparison passes over, pig_walk's static with the heel and toe exchanged in both, has them alike.)
    exchanged = tuple(replace(x, protocol=True) if x.against_model and sole[x.segment] == 1 else x for x in exchanged)
    for x in exchanged:
        say(Progress("markers", x.text([t.source or f"trial {k + 1}" for k, t in enumerate(trials)])
                     + ("; their positions there left out" if x.odd is not None else
                        "; their places in the base model exchanged for the fit" if x.protocol else
                        "; check the labels")))
    # Unlabelled trajectories (Vicon's '*115'): ghosts, reflections or markers the operator left
    # unnamed; nothing says which landmark they are, so they are never placed as new markers.
    unknown = [lab for lab in labels if lab not in known and (not UNLABELLED.fullmatch(lab) or lab in declared)]
    placed: list[NewMarker] = []
    # each trial's relative marker motion (_trial_motion), measured once if needed
    motion: list[float] | None = own_motion if own_motion and len(trials) > 1 else None
    if unknown and run.new_markers:
        say(Progress("markers", f"placing {len(unknown)} trial markers the model does not know"))
        motion = _trial_motion(members, judged)
        placed = _assign_new_markers(model, trials, unknown, motion, declared, bare)
    if motion is None and len(trials) > 1:
        motion = _trial_motion(members, judged)  # which trials are still (_still_lengths, moved and re-placed markers)
    new = {m.label: m.segment for m in placed if m.segment is not None}
    ours = {*known, *new}
    jittery = tuple((i, x) for i, d in enumerate(damage or ()) for x in d[1] if x.label in ours)
    for i, x in jittery:
        say(Progress("markers", f"{trials[i].source or f'trial {i + 1}'}: {x.text()}"))
    ignored = tuple(lab for lab in labels if lab not in known and lab not in new)
    at = {m.label: m.position for m in placed if m.position is not None}  # (hosts.cluster_hosts)
    subject = add_markers(model, {lab: (seg, at.get(lab, np.zeros(3))) for lab, seg in new.items()}) if new else model
    # Segments the markers cannot place (calibrate.model.resolve): refuse without a root pose, else lock
    # the coordinates the markers do not see (their segments ride on their parents).
    from ..model.resolve import carried_joint, carry_refusal, line_root_holds, resolve_carrying, root_group

    visible = {lab for t in trials for i, lab in enumerate(t.labels) if np.isfinite(t.markers[:, i]).all(1).any()}
    # No marker on the root and every one on one of its branches (an upper-body or one-leg trial): the root rides with
    # that branch's top, the DoFs between them held (resolve.carried_root); reported as the unresolved are.  (Judged
    # on the new labels with a place only: the others sit at their segment's origin until the fit places them.)
    placed_shown = [lab for lab in [*shared, *(n for n in new if n in at)] if lab in visible]
    waiting = [lab for lab in new if lab in declared and lab not in at]  # declared, with no place read yet
    # The new labels without a place yet sit at their segment's origin, its joint's centre, where they would place
    # none of its turns: judged at provisional places about it, as the user's word (the declared) or the tests' that
    # they ride on it (a lower-body model's torso that carries only the declared trunk markers: its lumbar locked
    # before, the markers then riding with the pelvis; MOtoNMS's UWA fast walk, its right forearm cluster put on the
    # ulna by its turn about the elbow: the elbow locked, the cluster 30-35 mm RMS off).
    # (The tests' labels on the root's branch stay at their origins: whether the markers place the root, or carry it
    # with a branch, is judged on the labels with a place, as before.)
    trunk = root_group(model)
    provisional = [lab for lab in new if lab not in at and (lab in waiting or new[lab] not in trunk)]
    probe = add_markers(model, {lab: (seg, at[lab] if lab in at else _provisional(k) if lab in provisional
                                      else np.zeros(3)) for k, (lab, seg) in enumerate(new.items())}) \
        if provisional else subject
    res, carried = resolve_carrying(probe, [*shared, *new], locked=[d for d, _ in settings.lock], carry=placed_shown)
    if not res.root_resolved:
        why = carry_refusal(subject, placed_shown, locked=[d for d, _ in settings.lock])
        raise CalibrateError(f"{where}: its {len(shared)} markers shared with {model.path.name} cannot place the "
                             f"{model.root} (unresolved: {', '.join(res.names)}){why}"
                             f"{_declared_unplaced(model, new, waiting)}; rename the trial labels "
                             f"(--markers map.toml) or use a model with this marker set")
    without = [lab for lab in [*shared, *new] if lab in visible and lab not in waiting]
    if waiting and not resolve_carrying(subject, without, locked=[d for d, _ in settings.lock],
                                        carry=placed_shown)[0].root_resolved:
        # The root placed only by counting the declared labels that no trial's model markers place: their places
        # would come from start poses nothing fixes (a simulated CAST session without its pelvis cluster, its static
        # showing the knees and the sternum: knee axes 47-89 deg off, a shank scaled 0.69, flagged but unusable).
        raise CalibrateError(f"{where}: the model's markers the trials show ({len(shared)}) and the new labels placed "
                             f"cannot place the {model.root} without the marker map's [segments] labels, whose places "
                             f"nothing reads{_declared_unplaced(model, new, waiting)}")
    if run.auto_hold:
        # The root's markers on one line (a markerless pelvis: two hip keypoints): its turn about it held by the
        # trunk's, as Pose2Sim's IK setup holds it (line_root_holds); reported and locked as the unresolved are.  A new
        # label without a place sits at its segment's origin until the start places it, and an OpenSim pelvis's origin
        # lies between its ASIS markers: where the root carries one, the trials say whether its markers are on a line
        # (gait2392's V.Sacral on Rajagopal2016: its lumbar held, the pelvis tilted 56 deg, the trunk scaled 0.2).
        shown = [lab for lab in [*shared, *new] if lab in visible]
        root = root_group(subject)
        on_root = [lab for lab in shown if subject.markers[subject.marker_index(lab)].segment in root]
        unplaced = any(lab not in at and new[lab] in root for lab in new)
        line = () if unplaced and _off_line(trials, on_root) else line_root_holds(
            subject, shown, locked=[*(d for d, _ in settings.lock), *res.lock])
        if line:
            res = replace(res, segments=res.segments + line, lock=res.lock + tuple(u.coordinates[0] for u in line))
    # A trial that shows fewer markers than the others may not place segments they place (a static with the arms, a
    # walk without): its frames' coordinates there rest on the priors and the neighbouring frames, not on its markers.
    # (A trial of new markers alone is judged once they are placed: at their segments' origins they place nothing.
    # Judged at the provisional places the calibration's markers were: AUC's walk, without the static's medial knee and
    # ankle markers, had its torso, which four new trunk markers at the torso's origin place nowhere, called unplaced.)
    by_trial = tuple((i, u) for i, u in ((i, _trial_unplaced(probe, t, [*shared, *new], visible, res, settings))
                                         for i, t in enumerate(trials) if i not in bare) if u) \
        if len(trials) > 1 else ()
    for i, u in by_trial:
        say(Progress("markers", f"{trials[i].source or f'trial {i + 1}'}: its markers do not place "
                                f"{', '.join(x.segment for x in u)}, which the other trials place"))
    if res.lock:
        say(Progress("markers", f"{len(res.segments)} segments unresolved ({', '.join(res.names)}); locking "
                                f"{', '.join(res.lock)}"))
        settings = replace(settings, lock=settings.lock + tuple(
            (d, float(np.clip(0.0, subject.dofs[subject.dof_index(d)].lower, subject.dofs[subject.dof_index(d)].upper)))
            for d in res.lock))
    # A segment the trials reach only through a cluster of new labels (hosts.cluster_hosts: a head band): the
    # labels' places and its joint's centre would trade, so the centre keeps the base model's place.
    banded = {m.segment for m in placed if m.position is not None and m.segment}
    banded_joints = tuple(j.name for j in subject.joints if j.child in banded and j.name not in settings.hold_centres)
    if banded_joints:
        say(Progress("markers", f"{', '.join(banded_joints)}: centre held at the base model's (its segment carries "
                                "only a cluster of new labels)"))
        settings = replace(settings, hold_centres=settings.hold_centres + banded_joints)
    still_only = _still_only(members, judged, motion)
    still_centres = _still_centres(subject, settings, judged, motion) if run.auto_hold else ()
    if still_centres:
        say(Progress("markers", f"still trials: no motion places {', '.join(still_centres)}; their centres held "
                                "at the base model's offset from their segments' markers"))
        settings = replace(settings, hold_centres=settings.hold_centres + still_centres)
    still_axes = _still_axes(subject, settings, judged, motion) if run.auto_hold else ()
    # The subject's size from the cleaned trials' marker distances: pig_walk's RFRM on the floor for 212 of 300 frames,
    # all of them left out of the seed and the solve, had set the right arm's size from the floor (0.72, 0.86 without)
    # and the right shoulder ended 49 mm from the calibration with them unseen.
    size = size_from_markers(model, judged)
    del judged  # the cleaned copies (a long trial's markers once more) are not needed past the judgments
    as_given = settings.hold_axes  # the axes held for the run's own reasons are reported as found (held_axes)
    if still_axes:
        say(Progress("markers", f"still trials: no motion places the axes of {', '.join(still_axes)}; held at the "
                                "base model's"))
        settings = replace(settings, hold_axes=settings.hold_axes + still_axes)
    obs = np.concatenate([marker_columns(subject, t) for t in trials])
    spans = trial_spans(trials)
    for x in exchanged:  # the trial the base model says has them exchanged: their positions there left out
        if x.odd is not None:
            obs[spans[x.odd], [subject.marker_index(n) for n in x.labels]] = np.nan
    seen = np.all(np.isfinite(obs), axis=2)
    unused = tuple(n for k, n in enumerate(subject.marker_names) if not seen[:, k].any() and n in known)
    blind = _segments_without_data(subject, {n for k, n in enumerate(subject.marker_names) if seen[:, k].any()})
    if carried is not None:  # the segments that carry the marked part: their geometry trades with the root's pose
        blind += [j.parent for j in subject.joints if set(j.dofs) & set(carried.coordinates) and j.parent not in blind]
    if blind:  # nothing in the data reaches their geometry: held at the base model's (Settings.hold_segments)
        settings = replace(settings, hold_segments=tuple(sorted(set(settings.hold_segments) | set(blind))))
    n_good = int(np.sum(seen.sum(1) >= 3))
    if n_good < MIN_FRAMES and obs.shape[0] < MIN_FRAMES:  # a one-frame static export, alone
        raise CalibrateError(f"{where}: {obs.shape[0]} frame{'s' if obs.shape[0] != 1 else ''} in all; calibrate "
                             f"needs at least {MIN_FRAMES}: give a movement trial with it (calibrate STATIC WALK "
                             "MODEL) or export more frames of the static")
    if n_good < MIN_FRAMES:
        raise CalibrateError(f"{where}: only {n_good} frames show 3 or more of the model's markers; "
                             f"need at least {MIN_FRAMES} (check the labels and gaps)")
    _check_size(model, trials, size)
    _check_rate(model, trials)
    if not matched:
        _check_handedness(model, trials)
    _check_one_subject(model, trials)
    apart = trials_apart(model, trials)
    for i, j, misfit, pairs in apart:
        say(Progress("markers", f"{trials[i].source or f'trial {i + 1}'} and {trials[j].source or f'trial {j + 1}'}: "
                                f"their markers on each segment are {100 * misfit:.0f} % apart (median over {pairs} "
                                "pairs): trials of two subjects?"))
    if run.seed and still_only is not None:
        # No joint turns: MTB's joint centres need a joint that turns (it found none on any real static, in up to
        # 5 s of trilateration starts), so the base model scaled to the subject's size from marker distances, its
        # markers where the static shows them, starts.
        say(Progress("seed", "the subject's size from marker distances (no joint turns: no MTB joint centres)"))
        seed = seed_parameters(model, trials[0], joints=JointEstimates((), (), 0.0), extra_markers=new, size=size,
                               jumps=None if damaged is None else damaged[0])
        which = "no trial turns a" if len(trials) > 1 else "the trial turns no"
        seed = replace(seed, notes=(f"no joint-centre seed: {which} joint (MTB needs joints that turn); the base "
                                    "model scaled to the marker distances used", *seed.notes))
    elif run.seed:
        say(Progress("seed", "the subject's size from marker distances, then joint centres (MTB)"))
        # The trial whose markers on different segments move most relative to each other (a static trial's
        # barely do): the one the joint-centre seed can use.
        pick = int(np.argmax(motion)) if motion is not None else 0  # (measured for more than one trial)
        seed = seed_parameters(model, trials[pick], extra_markers=new, size=size,
                               jumps=None if damaged is None else damaged[pick],
                               progress=Countdown(say, "seed", "joint centres (MTB)"))
        if len(trials) > 1:
            seed = Seed(seed.params, (f"seeded from {trials[pick].source or f'trial {pick + 1}'} (the trial with "
                                      f"the most joint motion)", *seed.notes), seed.joints, seed.seconds)
    else:
        seed = Seed(model.parameters(), ("seed switched off; starting from the base model",), None, 0.0)
    if "scale" not in settings.free:
        seed = Seed(Parameters(np.ones_like(seed.params.scale), *(getattr(seed.params, b) for b in ("centre", "axis",
                                                                                                     "marker"))),
                    seed.notes, seed.joints, seed.seconds)
    params0 = _on_model(subject, model, _fixed_groups(model.parameters(), seed.params, settings.free))
    params0 = _hold_segments(subject, params0, settings.hold_segments, settings.hold_centres)
    params0 = _unseen_at_base(subject, model, params0, unused)
    protocol = [x.labels for x in exchanged if x.protocol]
    params0 = _protocol_places(subject, params0, protocol)
    times["seed"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(Progress("build", "residuals and Jacobian (CasADi)"))
    kin = kinematics if kinematics is not None and subject is model else build_kinematics(subject)
    # Swapped labels and spikes that jump away and back are left out before the start and the solve (as
    # from the seed): a few frames of a knee and an ankle label exchanged drag a leg into a wrong minimum
    # before the solve's own outlier rejection can see them.  So are a marker's positions where it stays at one place
    # in the lab while its segment moves (fallen off: seeding.fallen_samples).  They are reported with the other
    # outliers.
    jumped = jumped_samples(subject, trials, found=damaged) if damaged is not None \
        else np.zeros(obs.shape[:2], dtype=bool)
    tested = np.zeros_like(jumped)  # an earlier run's outliers, left out from the start (refit_outliers)
    for o in gone:
        if o.marker in subject.marker_names:
            tested[spans[o.trial].start + o.frame, subject.marker_index(o.marker)] = True
    jumped |= tested
    raw = obs
    if jumped.any():
        say(Progress("markers", f"{int(jumped.sum())} positions jump away and back (swapped labels, spikes), jitter or "
                                "stay behind while their segment moves (a marker fallen off); left out"))
        obs = np.where(jumped[..., None], np.nan, obs)
    problem = Problem(subject, obs, settings.problem, kin, progress=say,
                      base=_protocol_places(subject, subject.parameters(), protocol) if protocol else None)
    lengths = _still_lengths(trials, motion, run.still_weight) if motion is not None else None
    if lengths is not None:
        still = [t.source or f"trial {i + 1}" for i, (t, n) in enumerate(zip(trials, lengths, strict=True))
                 if n < t.n_frames]
        say(Progress("build", f"{', '.join(still)}: still (one pose repeated, its errors with it); "
                              f"{'its frames count' if len(still) == 1 else 'the frames of each count'} "
                              f"as {run.still_weight:g} frames in all"))
        problem = problem.with_frame_weight(np.concatenate([np.full(t.n_frames, n / t.n_frames)
                                                            for t, n in zip(trials, lengths, strict=True)]))
    times["build"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(Progress("start", "frame-wise inverse kinematics"))
    is_new = np.array([n in new for n in subject.marker_names])
    known_obs = np.where(is_new[None, :, None], np.nan, obs)  # new markers have no place yet: poses from the others
    if run.seed:
        base0 = _hold_segments(subject, _on_model(subject, model, model.parameters()), settings.hold_segments,
                               settings.hold_centres)
        seeded = "the MTB seed" if still_only is None else "the base model at the subject's size"
        posable = [k for k in range(len(trials)) if k not in bare]  # (a bare trial's frames show nothing known yet)
        params0, choice = choose_start(problem, known_obs, [spans[k] for k in posable],
                                       {seeded: params0, "the base model": base0}, say, solver, ahead=run.ahead,
                                       lengths=None if lengths is None else [lengths[k] for k in posable])
        seed = replace(seed, notes=(*seed.notes, choice), taken=params0 is not base0)
    evaluator = problem.frame_evaluator(params0.vector())
    # Each trial's first key frame also from a local solve from the default pose (the better fit taken): on
    # Rajagopal2016 the joint-by-joint search alone turned the walking left arm 154 deg from OpenSim's IK
    # (arm_rot_l; 41 deg with it).  Not in the race above: there it made pig_walk's race take the MTB seed,
    # whose lumbar then ended 64-66 mm out (docs/benchmarks.md).
    posed = Countdown(say, "start", "frame-wise inverse kinematics of every trial's frames")

    def trial_start(k: int, progress: bool = False) -> State:
        sl = spans[k]
        return start_poses(problem.kin, known_obs[sl], params0, key_stride(trials[k].rate), evaluator=evaluator,
                           progress=(lambda done: posed((sl.start + done * (sl.stop - sl.start)) / problem.F))
                           if progress else None, local=True)

    # Every second trial's poses are found ahead on the other core (calibrate.solve.ahead; no progress from
    # there), the others here: the same poses, 0.1 s sooner on pig_walk.
    odd = [k for k in range(1, len(trials), 2) if k not in bare]
    theirs = (trial_start(k) for k in odd)
    theirs = run_ahead(theirs) if run.ahead and len(odd) > 0 else theirs
    try:
        mine = {k: trial_start(k, progress=True) for k in range(0, len(trials), 2) if k not in bare}
        mine.update(zip(odd, theirs, strict=True))
    finally:
        theirs.close()  # a child still running (this process failed first) stopped at once
    if bare:  # their frames hold a posed trial's first pose until the new markers are placed (below)
        first = mine[min(mine)]
        mine.update({k: frames_of(first, np.zeros(spans[k].stop - spans[k].start, dtype=int)) for k in bare})
    start = stack_states([mine[k] for k in range(len(trials))])
    relabelled: list[ExchangedCluster] = list(early)
    sacral: dict[int, tuple[np.ndarray, str]] = {}
    if new:
        posed_obs = _without_trials(obs, spans, bare)  # the new markers' places read where the model's markers posed
        places = _new_places(subject, problem.kin, start, posed_obs, params0, placed)
        described = described_labels(trials)
        sacral = _far_sacral(places, _sacral_places(subject, params0, placed, known_obs, described, obs))
        if sacral:
            # The start's poses turned the pelvis about its ASIS line (_sacral_places): posed again with the sacral
            # marker where the model's spine markers put it, as a known marker, and the new markers placed from there.
            say(Progress("start", "frame-wise inverse kinematics again, the sacral marker between the model's "
                                  "posterior iliac spines"))
            params0 = params0.copy()
            for k, (offset, _) in sacral.items():
                params0.marker[k] = offset
            is_new[list(sacral)] = False
            known_obs = np.where(is_new[None, :, None], np.nan, obs)
            evaluator = problem.frame_evaluator(params0.vector())
            start = stack_states([trial_start(k) if k not in bare else frames_of(start, spans[k])
                                  for k in range(len(trials))])
            places = _new_places(subject, problem.kin, start, posed_obs, params0, placed)
        if motion is not None and len(trials) > 1 and run.outliers > 0:
            # A cluster's labels exchanged in a still trial against the moving ones (a symmetric plate labelled the
            # other way round), by their places at the start's poses, which the other markers set: read back there,
            # before the places and the fit are taken from them (moved.exchanged_clusters).
            idx, frames, local, _ = places
            trial_of0 = np.concatenate([np.full(sl.stop - sl.start, i) for i, sl in enumerate(spans)])
            found = exchanged_clusters(local, trial_of0[frames], [m < STILL_MOTION for m in motion],
                                       [subject.marker_names[k] for k in idx],
                                       [subject.markers[k].segment for k in idx])
            for x in found:
                say(Progress("markers", x.text(trials[x.trial].source or f"trial {x.trial + 1}")))
            if found:
                obs, raw, problem = _read_as(found, obs, raw, problem, spans)
                relabelled += found
                posed_obs = _without_trials(obs, spans, bare)
                places = _new_places(subject, problem.kin, start, posed_obs, params0, placed)
        unplaced_params, unplaced_new = params0, placed
        params0, base, placed = _place_new_markers(subject, places, params0, placed, sacral)
        problem = problem.with_base(base)
        start = replace(start, p=params0.vector())
        if bare:
            # The trials of clusters alone posed by their clusters, placed now (frame-wise IK at the start geometry)
            say(Progress("start", f"frame-wise inverse kinematics of {len(bare)} trial(s) of new markers alone, "
                                  "placed from the others"))
            start = _pose_bare(problem, start, obs, spans, bare, trials, params0)
            # A cluster the other trials name otherwise (a symmetric plate labelled the other way round in the static:
            # AddBiomechanics' Expert1), by which labelling poses the trials of clusters alone best (_bare_exchanges)
            found = _bare_exchanges(subject, problem, start, obs, spans, bare, trials, params0, placed)
            for x in found:
                say(Progress("markers", x.text(trials[x.trial].source or f"trial {x.trial + 1}",
                                               "the trials of its clusters alone")))
            if found:
                obs, raw, problem = _read_as(found, obs, raw, problem, spans)
                relabelled += found
                places = _new_places(subject, problem.kin, start, _without_trials(obs, spans, bare), unplaced_params,
                                     unplaced_new)
                params0, base, placed = _place_new_markers(subject, places, unplaced_params, unplaced_new, sacral)
                problem = problem.with_base(base)
                start = _pose_bare(problem, replace(start, p=params0.vector()), obs, spans, bare, trials, params0)
            at_places = add_markers(model, {m.label: (m.segment, m.position) for m in placed if m.segment})
            late = tuple((i, u) for i in bare
                         if (u := _trial_unplaced(at_places, trials[i], [*shared, *new], visible, res, settings)))
            for i, u in late:
                say(Progress("markers", f"{trials[i].source or f'trial {i + 1}'}: its markers do not place "
                                        f"{', '.join(x.segment for x in u)}, which the other trials place"))
            by_trial = tuple(sorted(by_trial + late, key=lambda iu: iu[0]))
    far: list[FarJoint] = []
    far_obs = None  # the still trials' positions left out beyond their far joints
    if run.far_joints and len(trials) > 1:
        # A still trial holding a joint where the moving trials never go (arms out in the static, at the
        # sides in the walk): its markers beyond it left out (calibrate.calibration.far_joints).
        motion = motion if motion is not None else _trial_motion(members, trials)
        Zs, Qs = absolute(problem.kin, start, spans)
        far = far_joints(subject, Zs, Qs, spans, [m < STILL_MOTION for m in motion], problem.seen)
        if far:
            out = np.zeros(problem.seen.shape, dtype=bool)
            for fj in far:
                say(Progress("markers", fj.text(trials[fj.trial].source or f"trial {fj.trial + 1}")))
                out[spans[fj.trial], [subject.marker_index(m) for m in fj.markers]] = True
            far_obs = np.where(out[..., None], problem.observed, np.nan)
            problem = problem.without(out)
    times["start"] = time.perf_counter() - t0
    initial = problem.marker_residuals(start)
    t0 = time.perf_counter()
    in_neutral, not_neutral = None, []
    if neutral is not None:
        in_neutral = np.zeros(problem.F, dtype=bool)
        in_neutral[spans[neutral]] = True
    # On every frame a marker's correlation time counts up to NOISE_TAU_SECONDS whatever the trials' rate.
    cap = tau_cap(np.array([t.rate for t in trials]), np.array([t.n_frames for t in trials]))
    # Which trials are still: their moved markers looked for (with run.moved_markers off, only the re-placed left out)
    still = [m < STILL_MOTION for m in motion] if motion is not None and len(trials) > 1 else None
    problem, state, summary, scatter, solved, moved, locks, narrow, narrow_centres, after = _solve(
        problem, start, spans, run, solver, say, lengths, cap, still, [t.source for t in trials],
        STILL_COARSE_FRAMES if still_only is not None else COARSE_FRAMES, relabel=run.outliers > 0)
    relabelled += after
    if after:  # the positions kept aside read as the fit's
        raw = relabel_columns(raw, spans, after, list(subject.marker_names))
        far_obs = None if far_obs is None else relabel_columns(far_obs, spans, after, list(subject.marker_names))
    held = tuple(d for d in problem.settings.hold_axes if d not in as_given)
    # As used: with the axes held and the hinges locked above.
    settings = replace(settings, hold_axes=problem.settings.hold_axes, lock=problem.settings.lock,
                       hold_centres=problem.settings.hold_centres)
    rejected: list[Outlier] = []
    hit = np.zeros(problem.F, dtype=bool)  # frames with a rejected marker position
    fixed = fixed_noise(problem, run)
    trial_of = np.concatenate([np.full(sl.stop - sl.start, i) for i, sl in enumerate(spans)])
    # Unless the trial was short enough to be solved whole, _solve fitted every frame's pose to the
    # subsample's geometry and learnt the noise there: the outliers are tested at those poses and every frame
    # then solved, once whatever the test found.
    unsolved = not solved
    observed = problem.observed.copy()  # before any rejection: what a rejected position was
    paused: Run | None = None  # the first solve on every frame, paused at FIRST_RUN_ATOL times the tolerance
    for settle in range(SETTLE_PASSES):
        # At the solution: the noise learnt again and the outliers tested against it, both at once; if either
        # changed the problem, solved again.
        changed = unsolved
        if fixed is not None and not unsolved:
            sigma, scatter = relearn(problem, state, fixed, say, trial_of, cap)
            if sigma is not None:
                problem = problem.with_noise(sigma)
                changed = True
        if rejected and not unsolved:
            # Rejected at poses not yet solved jointly, or against a scatter since learnt again: a position
            # that this solution fits within the outlier test (against the scatter just learnt) is an
            # observation again.
            at = [(spans[o.trial].start + o.frame, subject.marker_index(o.marker)) for o in rejected]
            back = np.zeros(problem.seen.shape, dtype=bool)
            back[tuple(np.array(at).T)] = True
            back &= ~find_outliers(problem.with_observed(np.where(back[..., None], observed, problem.observed)),
                                   state, run, scatter, trial_of)[0]
            if back.any():
                say(Progress("solve", f"{int(back.sum())} rejected marker positions fit the solution: kept"))
                problem = problem.with_observed(np.where(back[..., None], observed, problem.observed))
                rejected = [o for o, fk in zip(rejected, at, strict=True) if not back[fk]]
                changed = True
        found = 0
        h = None  # the leverage at the current problem and state: formed again only where a round changes them
        for _ in range(OUTLIER_ROUNDS if run.outliers > 0 else 0):
            # One spike drags its frame's pose, so every marker of that frame looks bad: reject only the
            # worst marker of each frame, re-solve those poses, and look again.
            if h is None:
                h, _ = leverage(problem, state, Countdown(say, "solve", "outlier test of every marker position"))
            bad, err = find_outliers(problem, state, run, scatter, trial_of, h=h)
            if not bad.any():
                break
            worst = np.where(bad, err, -1.0).argmax(axis=1)
            frames = np.flatnonzero(bad.any(axis=1))
            bad = np.zeros_like(bad)
            bad[frames, worst[frames]] = True
            for f, k in zip(frames, worst[frames], strict=True):
                i = next(i for i, sl in enumerate(spans) if sl.start <= f < sl.stop)
                rejected.append(Outlier(i, int(f - spans[i].start), subject.marker_names[k], float(err[f, k])))
            found += frames.size
            say(Progress("solve", f"{frames.size} marker positions rejected as outliers"))
            problem = problem.without(bad)
            # A spike or a swapped label drags its frame's pose (a leg folded to reach a swapped ankle
            # marker) further than a few steps undo: such frames restart from their unaffected neighbours'.
            new_hit = np.zeros_like(hit)
            new_hit[frames[~hit[frames]]] = True
            hit |= new_hit
            state = bridge(state, new_hit, hit, spans)
            # Only these frames' observations changed: their poses alone are fitted again (the frames are
            # independent with the geometry held), and their leverage formed again.
            sub = problem.subset(frames)
            part, _ = levenberg_marquardt(sub, frames_of(state, frames), solver, pose_only=True, max_iterations=10,
                                          progress=_clock(say, sub, solver, "poses, "))
            state = with_frames(state, frames, part)
            h[frames] = leverage(sub, part)[0]
        if not (found or changed):
            break
        if paused is not None:  # the problem changed: the paused solve ends where it stopped
            summary = _merge(summary, replace(paused.summary, final_cost=paused.cost))
            paused = None
        if unsolved:
            say(Progress("solve", f"all {problem.F} frames"))
        elif found:
            say(Progress("solve", "again without the outliers" + (" and with the noise learnt again" if changed
                                                                  else "")))
        else:
            say(Progress("solve", "again with the noise learnt again"))
        if unsolved and settle < SETTLE_PASSES - 1:
            # Another pass follows the first solve on every frame (the noise learnt again at its solution, the
            # outliers tested against it) and changes the problem by more than a few χ² units: the solve pauses
            # once a step lowers the cost by less than FIRST_RUN_ATOL times the tolerance, and goes on from there,
            # as one run would, only if the pass changes nothing.
            limit = FIRST_RUN_ATOL * solver.atol
            first = Run(problem, state, solver, progress=IterationClock(say, "all frames, ", limit, solver.ftol))
            first.advance(until=lambda s, at=limit: s.accepted > 1 and s.cost_history[-2] - s.cost_history[-1] < at)
            state = first.state
            if first.done:
                summary = _merge(summary, first.summary)
            else:
                paused = first
                paused.suspend()  # its frame blocks go while the pass runs
            first = None  # the paused run is held (and let go) by `paused` alone
        else:
            state, again = levenberg_marquardt(problem, state, solver, progress=IterationClock(
                say, "all frames, ", solver.atol, solver.ftol) if unsolved else _clock(say, problem, solver, "again, "))
            summary = _merge(summary, again)
        unsolved = False
    if paused is not None:  # nothing changed after the first solve on every frame: it goes on to the tolerance
        say(Progress("solve", "again, to the tolerance"))
        state, again = paused.finish()
        summary = _merge(summary, again)
    kept: list[MovedMarker] = []
    apart_places: list[PlacesApart] = []
    look_moved = not run.moved_markers and motion is not None and len(trials) > 1
    look_apart = motion is not None and sum(m >= STILL_MOTION for m in motion) >= 2
    if look_moved or look_apart:
        # Where each frame puts each marker on its segment, on at most MOVED_SAMPLE evenly spaced frames of each
        # trial (its places' mean and spread need no more, and a long trial's every frame would hold (F, markers, 3,
        # 3) arrays at once), read once for both looks below.
        idx = np.concatenate([sl.start + even_frames(sl.stop - sl.start, MOVED_SAMPLE) for sl in spans])
        sample, at = problem.subset(idx), frames_of(state, idx)
        places = marker_places(sample, at)
        if look_moved:
            # Markers a still trial shows elsewhere on their segment than the moving trials, looked for but kept
            # (Settings.moved_markers off): named, so that the user sees what pulls the geometry (gait2392's static
            # acromia, 53-63 mm, and its back centre 120 mm from the base model's) and the option that leaves them
            # out.
            kept = moved_markers(sample, at, trial_of[idx], [m < STILL_MOTION for m in motion], places=places)
        if look_apart:
            # Moving trials that put markers far apart on their segments (a squat's trunk and shoulder-blade markers
            # against a walk's): named, with what to do; the geometry took a compromise between them.
            apart_places = places_apart(sample, at, trial_of[idx], [m >= STILL_MOTION for m in motion], places=places)
    if far_obs is not None:
        # The still trials' angles beyond their far joints as their own markers show them at this geometry (the
        # markers left out of the fit reach no other coordinate: the cost keeps, but for joint limits), before
        # a turn of the segment frames below reads them (a neutral static's arms).
        state = refit_beyond(problem.kin, state, far_obs, far, spans, problem.locked, problem.frame_evaluator(state.p))
    # Last (with the neutral trial's turn and the centres' slide below), where Settings.segment_frames says so
    # (by default for an OpenSim model): the segment frames turned to where their markers put them, the frames in
    # which the lab's model defines its joint angles (align_markers).  A change of gauge (the data fit stays), so
    # no solve may follow and undo it.
    if run.segment_frames == "markers":
        say(Progress("solve", "segment frames turned to where their markers put them"))
        state = align_markers(problem, state, solver)
    pose_used: dict[str, float] = {}
    pose_unset: list[str] = []
    if in_neutral is not None:
        # Last: a change of gauge (the data fit stays), so no solve may follow and undo it.  A coordinate the run
        # holds (locked, auto-locked) stays at its value: a pose naming it at another is not met there.
        held_at = dict(problem.settings.lock)
        if pose is not None:
            pose_used = {n: v for n, v in pose.items() if n not in held_at}
            pose_unset = [n for n, v in pose.items() if n in held_at and not math.isclose(held_at[n], v, abs_tol=1e-9)]
        say(Progress("solve", "segment frames turned to " + (
            f"{', '.join(f'{n} {math.degrees(v):.3g}' for n, v in pose_used.items())} deg on average"
            if pose is not None else "zero joint angles") + f" in {trials[neutral].source or 'the neutral trial'}"))
        state, not_neutral, unset = align_neutral(problem, state, in_neutral, solver,
                                                  pose_used if pose is not None else None)
        pose_unset += unset
        pose_used = {n: v for n, v in pose_used.items() if n not in unset}
        summary = replace(summary, final_cost=problem.cost(state), termination=summary.termination
                          + "; then the segment frames turned to the neutral trial (the priors' cost changes)")
    # Last (with the neutral trial's turn): every hinge centre slid along its axis to where the priors want it
    # (Problem.slide_centres): no marker and no joint angle moves, only the priors' cost falls.
    # Where no one measured a knee's, ankle's or elbow's width, the population's: the base model's lateral marker
    # distance.
    population = population_widths(problem)
    slid = replace(state, p=problem.slide_centres(state.p, population))
    by_width = problem.width_placed(slid.p, population)  # their child's markers' places along the axis follow the width
    # The report lists with them the knees and ankles the slide cannot move (their child held: no foot markers) that
    # the solve placed by the population's width (Problem.unslid_width_terms).
    population += tuple(problem.model.joints[ji].name for ji, *_, per, _ in problem.unslid_width_terms() if per > 0)
    if far_obs is not None and (run.segment_frames == "markers" or in_neutral is not None):
        # Again at the turned frames: a turn re-solves the poses from the fit's markers, which do not reach them.
        slid = refit_beyond(problem.kin, slid, far_obs, far, spans, problem.locked, problem.frame_evaluator(slid.p))
    slid = _blind_at_size(problem, slid, blind, None if carried is None else carried_joint(subject, carried).name)
    summary = replace(summary, final_cost=problem.cost(slid))
    state = slid
    times["solve"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    cov = covariance(problem, state, progress=Countdown(say, "covariance", "the parameters' posterior covariance"))
    params = subject.unpack(state.p)
    changes = parameter_changes(problem, state.p, cov.matrix, cov.prior_only, by_width)
    length_sd = length_differences(problem, state.p, cov.matrix, cov.prior_only)
    mirror_sd = mirror_differences(problem, state.p, cov.matrix, cov.prior_only)
    Z, Q = absolute(problem.kin, state, spans)
    if pose_used:  # what the static holds at the end (a far arm's angles are fitted again after the turn): a named
        # angle more than POSE_MISS from its value is said, with where it ended, rather than claimed
        at_static = FrameLayout.angles(Z[spans[neutral]]).mean(axis=0)
        ended = {n: float(at_static[subject.dof_index(n)]) for n in pose_used}
        missed = [n for n in pose_used if abs(ended[n] - pose_used[n]) > POSE_MISS]
        pose_unset += [f"{n} ({math.degrees(ended[n]):.1f} deg)" for n in missed]
        pose_used = {n: v for n, v in pose_used.items() if n not in missed}
    # A coordinate no seen marker moves in a frame (a hand's one marker hidden) kept its start there; the motions
    # bridge it linearly between the frames either side that see one (solve.ik.bridge_unseen: a simulated walk's
    # wrists had ended 5-12 deg off in 0.6-1.8 s gaps, 3-5 bridged).
    Zm = Z.copy()
    for sl in spans:
        bridge_unseen(problem.kin, problem.seen[sl], Zm[sl])
    # Frames whose markers do not place the pelvis (the subject walking into or out of the capture volume), or a
    # segment (a thigh showing its knee marker alone): any pose that puts their few markers in place fitted them;
    # those coordinates are bridged from the frames either side that place them (held at a trial's edge), and the
    # report lists the frames.
    from ..model.resolve import unplaced_frames

    Qm = Q.copy()
    locked_names = [n for n, _ in problem.settings.lock]
    bridged: list[tuple[int, ...]] = []  # per trial, the frames that do not place the root
    partial = {i for i, _ in by_trial}  # a trial that places less than the others: held below (_hold_unplaced)
    root_placed: dict[int, tuple[int, int]] = {}  # per trial judged: frames placing the root, frames showing some
    for i, sl in enumerate(spans):
        # (a trial whose frames all show the same markers has no frame to bridge from; not one the others out-place,
        # its markers place the root as the trials' together do, or the run was refused before the solve)
        if i in partial or (problem.seen[sl] == problem.seen[sl.start]).all():
            bridged.append(())
            if i not in partial:
                root_placed[i] = (sl.stop - sl.start, sl.stop - sl.start)
            continue
        root_off, dofs_off = unplaced_frames(subject, problem.seen[sl], locked=locked_names)
        # (of the frames that show a marker's worth of the subject: a recording's stretch before the subject walks in
        # shows none, fits nothing and bends nothing)
        root_placed[i] = (int((~root_off).sum()), int((problem.seen[sl].sum(axis=1) >= SHOWN_MARKERS).sum()))
        bridge_unplaced(root_off, dofs_off, Zm[sl], Qm[sl])
        if (dofs_off & ~root_off[:, None]).any():  # part of a chain bridged: the rest fitted again to what it shows
            solver = FrameSolver(problem.kin, state.p, problem.frame_evaluator(state.p), margin=LIMIT_MARGIN)
            refit_bridged(solver, dofs_off, root_off, Zm[sl], Qm[sl], problem.observed[sl], problem.seen[sl],
                          FrameLayout.angle(np.flatnonzero(problem.locked)))
        bridged.append(tuple(int(f) for f in np.flatnonzero(root_off)) if not root_off.all() else ())
    if root_placed and all(n < ROOT_PLACED_MIN * shown for n, shown in root_placed.values()):
        # Nearly every frame's pose bridged from a few: a fit of interpolations (kineticstoolkit's racing_full on
        # human.urdf, an upper body's trial whose sternum and one acromion place the torso in 12 of its 700 frames:
        # a humerus scaled 0.20)
        n, shown = max(root_placed.values(), key=lambda v: v[0] / max(v[1], 1))
        raise CalibrateError(f"{where}: its markers place the {model.root} in only {n} of the {shown} frames that "
                             f"show {SHOWN_MARKERS} or more (under {ROOT_PLACED_MIN:.0%}; the others show too few of "
                             f"them to pose it), so its poses and the geometry would rest on interpolation: add "
                             f"markers on the {model.root} or the segments next to it, or give a trial that shows them")
    seen_names = {mk.name for k, mk in enumerate(subject.markers) if problem.seen[:, k].any()}
    # (read on the motions as written: a frame's fit that its markers do not place is no joint's turn)
    notes = coordinate_notes(subject, FrameLayout.angles(Zm), _sampled_blocks(problem, state, scatter),
                             problem.settings, seen_names)
    # The neighbour of a hinge locked for trading (an ankle beside a locked subtalar) was judged with it and found
    # the better seen: no note tells the user to lock it too (pig_walk's left ankle, 60 deg through the walk).
    found = {n for lk in locks for n in lk.neighbours}
    notes = tuple(n for n in notes if not (isinstance(n, StillNote) and n.coordinate in found))
    if in_neutral is None and motion is not None and len(trials) > 1:
        # Beside a still trial with no neutral one, the zero of two free hinges across a markerless segment (the foot's,
        # ankle and subtalar across the talus) is the priors' and the solve's, not the markers' (Expert1's static:
        # its ankles 9 deg SD apart over 25 calibrations, each with another trial; --neutral: 2 deg); the note says
        # so and names the still trial to take it from.
        still_at = next((i + 1 for i, m in enumerate(motion) if m < STILL_MOTION), 0)
        if still_at:
            notes += zero_notes(subject, seen_names, {n for n, _ in problem.settings.lock}, still_at)
    times["covariance"] = time.perf_counter() - t0
    if jumped.any():  # their distance from where the fitted model puts them
        Zr = FrameLayout.coordinates(Z[:, FrameLayout.translation], FrameLayout.angles(Z))
        err = np.linalg.norm(problem.kin.batch(Zr, Q, params)[0] - raw, axis=2)
        rejected = [Outlier(int(trial_of[f]), int(f - spans[trial_of[f]].start), subject.marker_names[k],
                            float(err[f, k]), before=not tested[f, k]) for f, k in np.argwhere(jumped)] + rejected
    residuals = problem.marker_residuals(state)
    misplaced = _misfit(misplaced, residuals, np.isfinite(raw).all(axis=2), spans, subject)
    for i, m in misplaced:
        say(Progress("markers", f"{trials[i].source or f'trial {i + 1}'}: {m.text()}; check the label"))
    # The hip centres on a few hundred frames of each trial, against Harrington's regression on its pelvis markers
    # (HipMotion.from_regression: a walk's hips, which its motion does not place, ended outside the pelvis).
    hip_frames = [even_frames(sl.stop - sl.start, HIP_FRAMES) for sl in spans]
    hip_at = [(idx, problem.kin.batch(FrameLayout.coordinates(Z[sl][idx, FrameLayout.translation],
                                                              FrameLayout.angles(Z[sl][idx])), Q[sl][idx], params)[1])
              for idx, sl in zip(hip_frames, spans, strict=True)]
    # A locked coordinate at its value in every frame, to the bit (as `calibrate ik` writes it): the solve holds it
    # by a stiff penalty (LOCK_WEIGHT), which leaves it a few 1e-9 rad off (gait2392's and Rajagopal2016's locked
    # subtalars: 6e-9 and 1.6e-9 rad, 1e-7 deg in the .mot); set, the markers move by under a nanometre there.
    for name, value in problem.settings.lock:
        Zm[:, FrameLayout.angle(subject.dof_index(name))] = value
    # A trial that does not place segments the others place: their coordinates held there, as `calibrate ik` holds
    # them (its root, where carried, moved so the marked branch stays where the fit put it).
    held_in = tuple(i for i, us in by_trial if _hold_unplaced(problem.kin, params, Zm[spans[i]], Qm[spans[i]], us))
    motions = tuple(Motion(t.times.copy(), Zm[sl, FrameLayout.translation].copy(), Qm[sl].copy(),
                           FrameLayout.angles(Zm[sl]).copy(),
                           subject.dof_names) for t, sl in zip(trials, spans, strict=True))
    return Calibration(subject, trials, settings, params, motions, residuals, initial, summary, seed, changes,
                       times, ignored, unused, problem.compiled, base_model=model, new_markers=tuple(placed),
                       outliers=tuple(rejected), coordinate_notes=notes, held_axes=held, auto_locked=locks,
                       narrow_axes=tuple(narrow.items()), narrow_centres=tuple(narrow_centres.items()),
                       axis_pairs=tuple((subject.dofs[d].name, subject.markers[k1].name, subject.markers[k2].name)
                                        for _, k1, k2, d in problem.pair_terms()),
                       pair_centres=tuple((subject.joints[ji].name, subject.markers[k1].name, subject.markers[k2].name)
                                          for ji, k1, k2, _ in problem.held_pair_terms()),
                       landmarks=tuple((subject.joints[ji].name, tuple(subject.markers[k].name for k in w),
                                        tuple(float(x) for x in t))
                                       for ji, _, w, t, _ in problem.landmark_terms()),
                       population_widths=population,
                       not_neutral=tuple(not_neutral),
                       pose=None if pose is None else tuple(pose_used.items()), pose_unset=tuple(pose_unset),
                       unresolved=res.segments, unplaced_in_trial=by_trial, unplaced_held=held_in,
                       unplaced_frames=tuple(bridged),
                       noise={n: float(v) for n, v in zip(subject.marker_names, scatter, strict=True)},
                       noise_weight={n: float(v) for n, v in zip(subject.marker_names, problem.sigma, strict=True)},
                       noise_learnt=run.learn_noise, misplaced=misplaced, jittery=jittery, exchanged=exchanged,
                       exchanged_back=exchanged_back_, trials_apart=apart,
                       moved=tuple(moved), relabelled=tuple(relabelled),
                       moved_kept=tuple(kept), places_apart=tuple(apart_places),
                       far_joints=tuple(far), still_only=still_only, still_centres=still_centres,
                       cluster_centres=banded_joints,
                       trial_weights=() if lengths is None else tuple(float(n) for n in lengths),
                       joint_markers=_joint_markers(problem, params, unused),
                       hip_motion=tuple(h for h in hip_motion(subject, motions, hip_at, trials, model)  # (a hip the
                                        # markers cannot turn: no motion to judge)
                                        if not set(subject.joints[subject.joint_index(h.joint)].dofs)
                                        <= {n for n, _ in problem.settings.lock}),
                       knee_axes=knee_axis_checks(subject, params, trials, motions), length_sd=length_sd,
                       mirror_sd=mirror_sd)


def _joint_markers(problem: Problem, params: Parameters, unused: Sequence[str]) -> tuple[JointCentreMarker, ...]:
    """The joint-centre markers the trials show (Problem.joint_markers), with their offsets from their centres."""
    m = problem.model

    def offset(P: Parameters, k: int, j: int, on_parent: bool) -> float:
        seg = m.segment_index(m.markers[k].segment)
        return float(P.scale[seg] * np.linalg.norm(P.marker[k] - (P.centre[j] if on_parent else 0.0)))

    return tuple(JointCentreMarker(m.markers[t.marker].name, m.joints[t.joint].name,
                                   offset(params, t.marker, t.joint, t.on_parent),
                                   offset(problem.base, t.marker, t.joint, t.on_parent))
                 for t in problem.joint_markers() if m.markers[t.marker].name not in unused)


def _sampled_blocks(problem: Problem, state: State, scatter: np.ndarray) -> np.ndarray:
    """_frame_blocks at `state` on at most STILL_SAMPLE evenly spaced frames (what still_coordinates reads: a
    median over frames needs no more; a long trial's are never all formed at once)."""
    idx = even_frames(problem.F, STILL_SAMPLE)
    return _frame_blocks(problem.subset(idx), frames_of(state, idx), scatter)


def _frame_blocks(problem: Problem, state: State, scatter: np.ndarray) -> np.ndarray:
    """Each frame's block A_f of the normal equations at `state` as one frame's markers alone weigh it: under
    their scatter (the noise SDs without the correlation time) and every frame counted once, so that A_f⁻¹ is
    what one frame fixes its pose to.  The solver's weights read a frame as 1/τ of one (a marker's errors
    correlated over τ frames) and a still trial's frame as a fraction of one (Settings.still_weight): under them
    one frame's SD came out 3-4 times too wide on pig_walk's walk (its ankles, 17 deg SD over the frames against
    2.2 deg one frame fixes, called still; docs/benchmarks.md)."""
    sigma = np.where(np.isfinite(scatter) & (scatter > 0), scatter, problem.sigma)
    return problem.with_noise(sigma).with_frame_weight(None).linearize(state, with_parameters=False).A


def _hold_segments(model: Model, params: Parameters, segments: Sequence[str], centres: Sequence[str] = ()
                   ) -> Parameters:
    """`params` with the base model's geometry on `segments` (Settings.hold_segments): their scale, the
    joint centres and markers in them, the axes of the joints into them; and the base model's centres of the
    joints `centres` (Settings.hold_centres)."""
    if not segments and not centres:
        return params
    out, base, held = params.copy(), model.parameters(), set(segments)
    for i, sg in enumerate(model.segments):
        if sg.name in held:
            out.scale[i] = base.scale[i]
    for ji, j in enumerate(model.joints):
        if j.parent in held or j.name in centres:
            out.centre[ji] = base.centre[ji]
        if j.child in held:
            for d in j.dofs:
                out.axis[model.dof_index(d)] = base.axis[model.dof_index(d)]
    for k, mk in enumerate(model.markers):
        if mk.segment in held:
            out.marker[k] = base.marker[k]
    return out


def _hold_centres(problem: Problem, state: State, narrow: Mapping[str, tuple[float, float]],
                  say: Callable[[str | Progress], None]) -> tuple[Problem, State]:
    """The problem with the centres of `narrow` (_narrow_centres) held (Settings.hold_centres, the noise SDs kept) and
    the state with them where the hold puts them (_held_centre_places): the solve goes on from there."""
    say(Progress("solve", "the moving trials turn " + ", ".join(
        f"{n} through {math.degrees(t):.0f} deg (its centre carried {1000 * d:.0f} mm from the base model's at the "
        f"subject's scale)" for n, (t, d) in narrow.items())
        + f" at most about every axis but one (under {math.degrees(NARROW_TURN):.0f}: the skin's turn of the segments "
        "would place the centre, and a turn about one axis leaves it anywhere along it): holding "
        f"{'its centre' if len(narrow) == 1 else 'their centres'} at the base model's offset from the markers, "
        "solving again"))
    problem = problem.with_settings(replace(problem.settings, hold_centres=problem.settings.hold_centres
                                            + tuple(narrow)), sigma=problem.sigma)
    return problem, replace(state, p=_held_centre_places(problem, state.p, tuple(narrow)))


def _held_centre_places(problem: Problem, p: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """`p` with the centres of the joints `names` (held: the problem's hold_centres) where their hold puts them: the
    base model's offset from the centroid of the parent segment's seen markers, at the size of their layout (the
    held-centre prior's row at zero, Priors), or, with fewer than three such markers, the base model's place in the
    parent's frame."""
    out, L, base = p.copy(), problem.layout, problem.base.vector()
    markers = dict(problem.held_centres())
    for name in names:
        ji = problem.model.joint_index(name)
        ce = L.entries("centre", np.array([ji]))[0]
        if ji not in markers:
            out[ce] = base[ce]
            continue
        mid, x0, _, _, kappa = held_layout(p, base, ce, L.entries("marker", np.array(markers[ji])))
        out[ce] = mid + kappa * x0
    return out


BLIND_SIZED = 3  # segments the data size (free scale, a marker shown) before the unseen ones take their median


def _blind_at_size(problem: Problem, state: State, blind: Collection[str], carried: str | None = None) -> State:
    """`state` with each segment no data reach (`blind`: _segments_without_data, held at the base model's geometry)
    scaled to the subject's size as the calibration measured it: the median scale of the segments whose scale is free
    and that carry a marker the trials show.  Nothing on or below such a segment reaches the fit (and its held scale
    has no prior), so only its geometry and inertia in the written model change: an unseen hand, head or upper body
    the subject's size, not the base model's.  Unchanged where the scales are not free or fewer than BLIND_SIZED
    segments are sized by the data (a pelvis and one thigh marker size those two, not the subject).  `carried`: the
    joint into the marked part a markerless root rides with (carried_root), whose carriers are among `blind`: every
    frame's root moved so that its centre, and the marked part with it, stays where the fit put it."""
    model, L = problem.model, problem.layout
    shown = {model.markers[k].segment for k in np.flatnonzero(problem.seen.any(axis=0))}
    sized = [i for i, sg in enumerate(model.segments) if sg.name in shown and not L.block("scale", i).held]
    if not blind or len(sized) < BLIND_SIZED:
        return state
    p = state.p.copy()
    at = float(np.median(p[L.scale(np.array(sized))]))
    for name in blind:
        p[L.scale(model.segment_index(name))] = at
    if carried is None:
        return replace(state, p=p)
    Z, Q = problem.kin.absolute(state.Z, state.Q, state.B)
    k = model.joint_index(carried)
    moved = problem.kin.batch(Z, Q, p)[1][:, k] - problem.kin.batch(Z, Q, state.p)[1][:, k]
    Z = state.Z.copy()
    Z[:, FrameLayout.translation] -= moved
    return replace(state, Z=Z, p=p)


def _trial_unplaced(model: Model, trial: Trial, labels: Sequence[str], visible: Collection[str], res,
                    settings: Settings) -> tuple:
    """The segments (resolve.UnresolvedSegment) that `trial`'s markers among `labels` cannot place where the
    calibration's markers (`res`, every trial's; `visible`: the labels any trial shows) place them, under the
    calibration's locks (`settings.lock`).  None where the trial shows every label the calibration sees."""
    from ..model.resolve import resolve_carrying

    here = {x for k, x in enumerate(trial.labels) if np.isfinite(trial.markers[:, k]).all(1).any()}
    shown = [lab for lab in labels if lab in here]
    if len(shown) == sum(lab in visible for lab in labels):
        return ()
    here, carried = resolve_carrying(model, shown, locked=[d for d, _ in settings.lock])
    known = set(res.names)
    # (a carried root: its own pose there rests on the priors too, the calibration not holding those DoFs)
    return tuple(replace(u, coordinates=("root", *u.coordinates)) if u is carried else u
                 for u in here.segments if u.segment not in known)


def _hold_unplaced(kin: Kinematics, params: Parameters, Z: np.ndarray, Q: np.ndarray, unplaced: Sequence) -> bool:
    """One trial's poses (Z absolute (n, nz), Q (n, 4), both changed in place) with the coordinates of the segments it
    does not place (`unplaced`: _trial_unplaced's) at their held value, 0 clipped to the limits.  Where its root is
    carried (a first entry naming 'root' and the DoFs to the marked branch), each frame's root is moved so that the
    branch (its markers and joint centres, by the kinematics at `params`) stays where it was: the rigid fit of the
    branch's points at the held pose onto them (exact: only the root and the held DoFs change).  Returns False, and
    changes nothing, where the trial's root is unplaced but not carried."""
    model = kin.model
    root = next((u for u in unplaced if u.segment == model.root), None)
    carried = root is not None and "root" in root.coordinates and len(root.coordinates) > 1
    if root is not None and not carried:
        return False
    names = list(dict.fromkeys(c for u in unplaced for c in u.coordinates if c != "root"))
    cols = [FrameLayout.angle(model.dof_index(n)) for n in names]
    value = [float(np.clip(0.0, model.dofs[model.dof_index(n)].lower, model.dofs[model.dof_index(n)].upper))
             for n in names]
    if not carried:
        Z[:, cols] = value
        return True
    from ..model.resolve import carried_joint, descendants
    from ..model.rotations import matrix_quats
    from ..seed.geometry import kabsch_rotation

    branch = set(descendants(model)[carried_joint(model, root).child])
    mk = [k for k, m in enumerate(model.markers) if m.segment in branch]
    jc = [k for k, j in enumerate(model.joints) if j.child in branch]
    M, C = kin.batch(Z, Q, params)
    before = np.concatenate([M[:, mk], C[:, jc]], axis=1)
    Z[:, cols] = value
    Z[:, FrameLayout.translation] = 0.0
    M, C = kin.batch(Z, np.tile([0.0, 0.0, 0.0, 1.0], (len(Z), 1)), params)
    at = np.concatenate([M[:, mk], C[:, jc]], axis=1)  # the branch with the root at the origin, unturned
    ca, cb = at.mean(axis=1), before.mean(axis=1)
    R = kabsch_rotation(np.einsum("fpi,fpj->fij", at - ca[:, None], before - cb[:, None]))[0]
    Z[:, FrameLayout.translation] = cb - np.einsum("fij,fj->fi", R, ca)
    q = matrix_quats(R)
    q *= np.where(np.sum(q * Q, axis=1) < 0, -1.0, 1.0)[:, None]  # each on the side of the quaternion it replaces
    Q[:] = q
    return True


def _segments_without_data(model: Model, seen: set[str]) -> list[str]:
    """Segments with no seen marker on them or on any segment below them in the tree."""
    below: dict[str, bool] = {}
    for j in reversed(model.joints):  # children after parents in model order: walk leaves first
        below[j.child] = below.get(j.child, False) or any(m in seen for m in model.segments[
            model.segment_index(j.child)].markers)
        below[j.parent] = below.get(j.parent, False) or below[j.child]
    root = model.segments[0].name
    below[root] = below.get(root, False) or any(m in seen for m in model.segments[0].markers)
    return [s.name for s in model.segments if not below.get(s.name, False)]


def _solve(problem: Problem, start: State, spans: list[slice], run: PipelineOptions, solver: SolverOptions,
           say: Callable[[str], None], lengths: Sequence[float] | None = None, tau_max: float | None = None,
           still: Sequence[bool] | None = None, sources: Sequence[str] = (), coarse_frames: int = COARSE_FRAMES,
           relabel: bool = False) -> tuple[Problem, State, SolverSummary, np.ndarray, bool, list[MovedMarker],
                                           tuple[TradingLock, ...], dict[str, float], dict[str, float],
                                           list[ExchangedCluster]]:
    """The global solve: the geometry's basin on about `coarse_frames` evenly spaced frames (spread over the trials by
    their length; a long trial then through larger subsamples), then every frame's pose fitted to that geometry and
    the noise learnt on every frame.  With `run.auto_hold`, the axes of the coordinates that the subsample's
    solution shows still, or turning through less than NARROW_TURN with their axis far from the base model's, are
    held at the base model's and the subsample solved again.  Returns the problem (with those axes held and the
    noise learnt), the state, its summary, the markers' noise SDs, whether every frame was solved jointly (a short
    trial, solved whole; otherwise the caller's solve on every frame follows), the markers moved in a still trial,
    the hinges locked (trading_locks) and the axes held for their narrow turn (name -> turn, rad).  `lengths`: what
    each trial counts as in frames (_still_lengths), the subsamples spread and weighted by it.  `tau_max`: the
    longest correlation time learnt on every frame (noise.tau_cap; a subsample's rows lie frames apart: its
    own).  `still`: which trials are still, where the markers that sit elsewhere in them than in the moving trials
    are looked for after the first subsample solve (calibrate.calibration.moved; their positions there left out and
    the subsample solved again: with run.moved_markers off, only the re-placed ones, moved.replaced); with `relabel`,
    before that the labels a still trial exchanges against the moving trials (moved.exchanged_after_solve: read back,
    returned last)."""
    seen = problem.seen
    coarse = spread_frames(seen, spans, coarse_frames, lengths)
    coarse_w = subsample_weight(coarse, spans, lengths)
    fixed = fixed_noise(problem, run)
    scatter = problem.sigma.copy()  # the markers' noise SDs (learnt: without the correlation time)
    trial_of = np.concatenate([np.full(sl.stop - sl.start, i) for i, sl in enumerate(spans)])
    state = frames_of(start, coarse)
    whole = coarse.size == problem.F  # a short trial: its subsample is every frame

    def subsample(pr: Problem) -> Problem:
        return pr if whole else pr.subset(coarse, coarse_w)

    sub_trial = trial_of if whole else trial_of[coarse]  # the trial of each subsample row
    placed = _placed_rows(problem, None if whole else coarse, sub_trial) if run.auto_hold else None

    names = [sources[i] if i < len(sources) and sources[i] else f"trial {i + 1}" for i in range(len(spans))]
    moved: list[MovedMarker] = []
    locks: tuple[TradingLock, ...] = ()
    narrow: dict[str, float] = {}  # axes held because the moving trials turn them less than NARROW_TURN (rad)
    narrow_centres: dict[str, float] = {}  # centres held so (joint -> its largest angle's turn, rad)
    coarse_summary: SolverSummary | None = None
    looks = 0  # looks for moved markers so far (MOVED_PASSES)
    relabelled: list[ExchangedCluster] = []  # labels read back after the first solve (exchanged_after_solve)
    for round_ in range(max(HOLD_ROUNDS, MOVED_PASSES) + 2):  # + 1: the round after labels read back
        sub = subsample(problem)
        # On a subsample the polish after the gauge alignment is left to the run on every frame.  A round after
        # the first (axes held, moved markers left out) adds its iterations to the first's.
        state, part = _solve_geometry(sub, state, solver, say, polish=sub is problem)
        coarse_summary = part if coarse_summary is None else _merge(coarse_summary, part)
        # After axes are held the noise learnt so far carries over (holding a few still axes barely moves
        # the residuals); every frame learns it once more.  Learning it again here took Rajagopal's run
        # three more subsample solves, its weights wandering 22, 15, 11 % (docs/benchmarks.md).
        for _ in range(NOISE_ROUNDS if fixed is not None and round_ == 0 else 0):
            # The trial's own scatter, measured at this solution: re-weigh and solve again from here.
            # Every frame: the cap in seconds; a subsample's rows: its own (tau_max).
            sigma, scatter = relearn(sub, state, fixed, say, sub_trial,
                                     tau_max if whole else None)
            if sigma is None:
                break
            problem = problem.with_noise(sigma)
            sub = subsample(problem)
            state, again = _solve_geometry(sub, state, solver, say, polish=sub is problem)
            coarse_summary = _merge(coarse_summary, again)
        found = []
        exchanged = []
        if round_ == 0 and still is not None and relabel:
            # A still trial's labels of the model's own markers exchanged against the moving trials' (a cluster
            # labelled the other way round): read back, and the subsample solved again before the moved markers
            # are looked for (at this solution they would read as moved).
            exchanged = exchanged_after_solve(sub, state, sub_trial, still)
            for x in exchanged:
                say(Progress("markers", x.text(names[x.trial])))
            if exchanged:
                problem = problem.with_observed(relabel_columns(problem.observed, spans, exchanged,
                                                                list(problem.model.marker_names)))
                sub = subsample(problem)
                relabelled += exchanged
        if looks < MOVED_PASSES and still is not None and not exchanged:
            # Markers the still trials show elsewhere on their segment than the moving trials: their still
            # positions left out, and the subsample solved again from here (the moving trials' place kept).
            # A second look after that solve: with the worst gone, a slipped cluster's other markers stand out.
            looks += 1
            found = moved_markers(sub, state, sub_trial, still, moved)
            if not run.moved_markers:  # only the re-placed (REPLACED_MIN): skin-borne shifts wait for the option
                found = replaced(found, moved)
            for m in found:
                say(Progress("markers", m.text(names[m.trial]) + "; left out there"))
            if found:
                out = np.zeros(problem.seen.shape, dtype=bool)
                for m in found:
                    out[spans[m.trial], problem.model.marker_index(m.marker)] = True
                problem = problem.without(out)
                sub = subsample(problem)
                moved += found
        held = []
        if run.auto_hold and round_ < HOLD_ROUNDS:
            axes = {problem.model.dofs[d].name for d in sub.axis_dofs}
            angles = FrameLayout.angles(absolute(sub.kin, state)[0])
            spreads = coordinate_spreads(sub.model, angles, _frame_blocks(sub, state, scatter), sub.settings)
            seen_names = {mk.name for k, mk in enumerate(problem.model.markers) if problem.seen[:, k].any()}
            turns = _axis_turns(problem, state.p, axes)
            # Beyond the axis prior (none given: no limit to read a trade by).
            limit = FAR_FROM_PRIOR * problem.settings.priors.axis if problem.settings.priors.axis > 0 else math.inf
            # A pair's axes carried beyond their prior by the fit: which of the two one frame's markers fix less
            # well is read at the start's geometry, before the trade (one linearization of the subsample).
            first = None
            if max(turns.values(), default=0.0) > limit:
                st0 = frames_of(start, coarse)
                first = coordinate_spreads(sub.model, FrameLayout.angles(absolute(sub.kin, st0)[0]),
                                           _frame_blocks(sub, st0, scatter), sub.settings)
            new_locks = trading_locks(problem.model, spreads, seen_names, {n for n, _ in problem.settings.lock},
                                      turns, first, limit)
            # A locked hinge's neighbour is judged by the still test as any other coordinate: its turn no longer
            # shared, it is found (pig_walk's ankles turn 15-17 deg SD in the walk, one frame fixes them to 2.2-2.4).
            skip = {lk.coordinate for lk in new_locks}
            held = [name for name, _, _ in still_of(spreads) if name in axes and name not in skip]
            # Axes carried beyond their prior where the moving trials turn the joint too little to place them against
            # the skin's turn of the segments (NARROW_TURN).
            rows = (np.arange(len(angles)) if still is None or all(still) else
                    np.flatnonzero([not still[i] for i in sub_trial]))
            far = NARROW_FAR * problem.settings.priors.axis if problem.settings.priors.axis > 0 else math.inf
            for name in sorted(axes - set(held) - skip - {n for n, _ in problem.settings.lock}):
                if turns.get(name, 0.0) <= far:
                    continue
                d = problem.model.dof_index(name)
                th = angles[rows[placed[rows, d]], d]
                if th.size < 3:  # no frame's markers place it: no turn to read
                    continue
                turn = float(np.percentile(th, 98) - np.percentile(th, 2))
                if turn < NARROW_TURN:
                    held.append(name)
                    narrow[name] = turn
            # Centres carried beyond their prior where the moving trials turn the joint too little about every axis,
            # or every axis but one (the centre carried along that one), to place a centre of rotation against the
            # skin (_narrow_centres).  Judged here, on the round's
            # solution with the noise learnt: on the first solution, before it, the centres had not settled, and
            # pig_walk's lumbar and neck were held, its marker RMS 7.18 -> 8.17 mm (docs/benchmarks.md).
            new_centres = _narrow_centres(problem, state.p, angles[rows], skip, run.segment_frames == "markers",
                                          placed[rows])
        else:
            new_locks, new_centres = (), {}
        if not held and not found and not exchanged and not new_locks and not new_centres:
            break
        if new_locks:
            for lk in new_locks:
                why = (f"the fit carried their axes {math.degrees(lk.turned):.0f} deg from the base model's"
                       if lk.turned else "the trial does not separate them")
                say(f"solve: {lk.coordinate} and {' and '.join(lk.neighbours)} trade across {lk.bare} (no markers "
                    f"the trials show) and {why}: locking {lk.coordinate} at {math.degrees(lk.value):g} deg, solving "
                    + ("the subsample again from the start" if lk.turned else "again"))
            locks += new_locks
            options = replace(problem.settings, lock=problem.settings.lock + tuple((lk.coordinate, lk.value)
                                                                               for lk in new_locks))
            problem = problem.with_settings(options, sigma=problem.sigma)
            # The locked angle in every frame at its value and its axis (held by the lock) at the base model's; the
            # subsample solved again from this solution, or, where the trade had carried the pair's axes beyond their
            # priors, from the start (poses and geometry; the noise learnt so far kept): from the trade's solution,
            # where the axes and the foot's markers had wandered, gait2392 without its IK setup kept its left ankle
            # 9-12 deg from OpenSim's IK, from the start 4.2 deg; pig_walk's still subtalars, from the start, spread
            # its thighs' L/R over 4.8-5.9 % on copies 0.1 mm apart, against 4.2-5.2 (docs/benchmarks.md).
            restart = frames_of(start, coarse) if any(lk.turned for lk in new_locks) else state
            p, base, Z = restart.p.copy(), problem.base.vector(), restart.Z.copy()
            for lk in new_locks:
                d = problem.model.dof_index(lk.coordinate)
                k = problem.layout.axis(d)
                p[k] = base[k]
                Z[:, FrameLayout.angle(d)] = lk.value
            state = replace(restart, p=p, Z=Z)
        if held:
            quiet = [n for n in held if n not in narrow]
            turned = [f"{n} through {math.degrees(narrow[n]):.0f} deg" for n in held if n in narrow]
            say("solve: " + "; ".join(
                ([f"the trial does not show {', '.join(quiet)} moving"] if quiet else [])
                + ([f"the moving trials turn {', '.join(turned)} only (under {math.degrees(NARROW_TURN):.0f}: "
                    "the skin's turn of the segments would place the axis)"] if turned else []))
                + f": holding {'its axis' if len(held) == 1 else 'their axes'} at the base model's, solving again")
            options = replace(problem.settings, hold_axes=problem.settings.hold_axes + tuple(held))
            problem = problem.with_settings(options, sigma=problem.sigma)
            # A held axis is the base model's (the estimate of a still joint's axis is noise).  The solve
            # goes on from this solution, not from the start: the rest of the geometry has found its basin,
            # and started afresh under the learnt weights the subsample may settle in another (pig_walk:
            # femurs 30 % long, on a change of 1e-8 m in the start poses).
            p, base = state.p.copy(), problem.base.vector()
            for name in held:
                k = problem.layout.axis(problem.model.dof_index(name))
                p[k] = base[k]
            state = replace(state, p=p)
        if new_centres:
            problem, state = _hold_centres(problem, state, new_centres, say)
            narrow_centres.update({n: t for n, (t, _) in new_centres.items()})
    coarse_summary.rounds = round_ + 1
    if sub is problem:
        return problem, state, coarse_summary, scatter, True, moved, locks, narrow, narrow_centres, relabelled
    # The geometry's basin is found on the subsample; every frame then joins for the last steps.  A long
    # trial passes through larger subsamples first (LEVEL_GROWTH times the last, while the trial is
    # LEVEL_ROOM times longer still): where a flat valley of the geometry lets the optimum of 120 frames
    # lie far from that of 30 000, the crawl along it is walked at a fraction of the cost per iteration.
    solved, levels = coarse, []
    target = coarse.size * LEVEL_GROWTH
    while problem.F >= LEVEL_ROOM * target:
        idx = spread_frames(seen, spans, target, lengths)
        say(f"solve: {idx.size} evenly spaced frames")
        # The subsample's problem (and its blocks' buffers) is dropped as soon as it is solved.
        state, part = _solve_frames(problem.subset(idx, subsample_weight(idx, spans, lengths)),
                                    frames_of(_carried(state, solved, start, spans), idx), solved,
                                    solver, say, f"{idx.size} frames, ")
        levels.append((int(idx.size), part.iterations))
        solved, target = idx, target * LEVEL_GROWTH
        per_frame = part.seconds / max(part.iterations, 1) / idx.size  # s per iteration and frame, for the estimate
    # A long trial's first iteration on every frame takes a while before its line: say how long, from the
    # largest subsample's pace (the time per iteration is linear in the frames).
    # Every frame's pose fitted to the subsample's geometry and the noise learnt on every frame there: the
    # solve on every frame (_calibrate, after the outlier test) then starts under the weights every frame
    # shows.  Solved first under the subsample's weights and then again under these, pig_walk took two runs
    # of 15-50 steps where one now takes 16 (docs/benchmarks.md).
    say(f"solve: all {problem.F} frames: poses fitted to the subsample's geometry, the noise learnt there"
        + (f" (then about {per_frame * problem.F:.0f} s per iteration, at the {solved.size}-frame subsample's "
           "pace)" if levels else ""))
    state, _ = levenberg_marquardt(problem, _carried(state, solved, start, spans), solver, pose_only=True,
                                   max_iterations=POSE_ITERATIONS, progress=_clock(say, problem, solver, "poses, "))
    if fixed is not None:
        sigma, scatter = relearn(problem, state, fixed, say, trial_of, tau_max)
        if sigma is not None:
            problem = problem.with_noise(sigma)
    cost = problem.cost(state)
    summary = SolverSummary(initial_cost=cost, final_cost=cost, cost_history=[cost],
                            termination="not solved on every frame yet")
    summary.coarse = coarse_summary
    summary.coarse_frames = int(coarse.size)
    summary.levels = levels
    return problem, state, summary, scatter, False, moved, locks, narrow, narrow_centres, relabelled


def _placed_rows(problem: Problem, rows: np.ndarray | None, trial_of: np.ndarray) -> np.ndarray:
    """Which coordinates each of the frames `rows` (None: every frame) places by the markers it shows
    (model.resolve.unplaced_frames, within each trial: `trial_of`, the trial of each row): (rows, DoFs).  A frame that
    shows none of a joint's markers (BTKData's Gait.c3d: the subject outside the capture volume in 293 of its 487
    frames) fits any pose there; no turn of the joint is read from it."""
    from ..model.resolve import unplaced_frames

    seen = problem.seen if rows is None else problem.seen[rows]
    out = np.ones((seen.shape[0], problem.model.n_dofs), dtype=bool)
    locked = [n for n, _ in problem.settings.lock]
    for i in np.unique(trial_of):
        at = np.flatnonzero(trial_of == i)
        out[at] = ~unplaced_frames(problem.model, seen[at], locked=locked)[1]
    return out


def _narrow_centres(problem: Problem, p: np.ndarray, angles: np.ndarray, skip: Collection[str] = (),
                    marker_frames: bool = False, placed: np.ndarray | None = None) -> dict[str, tuple[float, float]]:
    """The ball (and universal) joints' centres to hold for the narrow turn of their joint: carried by the fit (`p`)
    beyond NARROW_CENTRE_FAR prior SDs from the base model's at the subject's scale, while the moving trials turn
    the joint through less than NARROW_TURN about every axis, or about every axis but one where the fit carried
    the centre along that one (identifiability.joint_turns; rows of `angles` the moving trials' frames, columns every
    DoF's absolute angle; `placed`, the coordinates each row's markers place (_placed_rows), the rows that do not
    place the joint's left out).  A centre of rotation is placed
    by the arcs its child's markers sweep about it; skin turns a segment against its bone by up to 4.4 deg in a
    walk, and arcs of a few degrees leave the centre in a flat valley the skin's shifts decide: Rajagopal's run turns
    its lumbar joint 9-16 deg and carried the back's centre 117 mm from the base model's, an AddBiomechanics walk's
    lumbar 64 mm (docs/benchmarks.md).  A turn about one axis alone leaves the centre anywhere along that axis:
    BTKData's PiG_Motion-FlatFoot-Full turns its lumbar 22 deg about one axis and 8 deg about any other, and carried
    the back's centre 75 mm on Rajagopal2016.osim, 60 of them along that axis (ALONG_AXIS; a centre carried across it
    the wide turn places, and is left free).  Not the joints whose DoFs are locked or in `skip` (a hinge locked for a
    trade), nor those a joint-centre marker the trials show places (a lab's hip centre), nor those held already.
    `marker_frames`: the distance is read, as the report will read it, with the segment frames turned to where
    their markers put them (Settings.segment_frames "markers", calibrate.problem.gauge.align_frames): in the
    solver's own frames gait2392's pelvis stood 15 deg from its markers' and its back's centre 52 mm from the base
    model's, in its markers' 72 mm.  Joint -> (its widest turn, or where one turn is wide its second, rad; the
    centre's distance from the base model's at the subject's scale, m)."""
    st = problem.settings
    if "centre" not in st.free or not st.priors.centre > 0 or angles.shape[0] < 3:
        return {}
    model = problem.model
    net: dict[int, np.ndarray] = {}  # each segment's turn to its markers' frame (its frame R becomes R N)
    P, B = model.unpack(problem.align_frames(p, MARKER_FRAMES, net=net)[0] if marker_frames else p), problem.base
    locked = {n for n, _ in st.lock} | set(skip)
    marked = {t.joint for t in problem.joint_markers() if problem.seen[:, t.marker].any()}
    balls = {b.name: b for b in problem.kin.balls}
    urdf = {u.name: u for u in model.urdf_joints}
    far = NARROW_CENTRE_FAR * st.priors.centre
    out: dict[str, tuple[float, float]] = {}
    for ji, j in enumerate(model.joints):
        if j.kind not in ("ball", "universal") or j.name in st.hold_centres or ji in marked or any(
                d in locked for d in j.dofs):
            continue
        si = model.segment_index(j.parent)
        shift = float(P.scale[si]) * (P.centre[ji] - B.centre[ji])  # in the parent's frame
        gap = float(np.linalg.norm(shift))
        dofs = [model.dof_index(d) for d in j.dofs]
        rows = np.ones(angles.shape[0], dtype=bool) if placed is None else placed[:, dofs].all(axis=1)
        if gap <= far or rows.sum() < 3:
            continue
        turns, axes = joint_turns(angles[np.ix_(rows, dofs)], balls.get(j.name))
        if turns[0] < NARROW_TURN:
            out[j.name] = (float(turns[0]), gap)
        elif len(turns) > 1 and turns[1] < NARROW_TURN and axes is not None:
            # One wide turn places the centre across its axis, not along it: a shift mostly along the axis (within
            # ALONG_AXIS of it) is the skin's; one across it the wide turn's (shd01's back, 192 mm, 80 deg from it).
            axis = net.get(si, np.eye(3)).T @ urdf[j.urdf_joints[0]].rotation @ axes[0]
            if abs(float(shift @ axis)) > math.cos(ALONG_AXIS) * gap:
                out[j.name] = (float(turns[1]), gap)
    return out


def _axis_turns(problem: Problem, p: np.ndarray, names: Collection[str]) -> dict[str, float]:
    """The angle (rad) of each named hinge or universal axis in `p` from the base model's."""
    base = problem.base.vector()
    out = {}
    for name in names:
        d = problem.model.dof_index(name)
        cos = float(problem.axis_direction(p, d) @ problem.axis_direction(base, d))
        out[name] = float(np.arccos(np.clip(cos, -1.0, 1.0)))
    return out


def _carried(state: State, solved: np.ndarray, start: State, spans: list[slice]) -> State:
    """Every frame's pose from a solution on the frames `solved` (spread_poses within each trial) and
    its geometry."""
    parts = []
    for sl in spans:
        mine = np.flatnonzero((solved >= sl.start) & (solved < sl.stop))
        parts.append(spread_poses(frames_of(state, mine), solved[mine] - sl.start, frames_of(start, sl)))
    return replace(stack_states(parts), p=state.p.copy())


def _solve_frames(problem: Problem, state: State, solved: np.ndarray, solver: SolverOptions,
                  say: Callable[[str], None], label: str,
                  progress: IterationClock | None = None) -> tuple[State, SolverSummary]:
    """Poses and geometry solved on `problem` from poses carried from the frames `solved` (_carried):
    where those were far apart, each pose is fitted to the geometry first."""
    gap = int(np.diff(solved).max(initial=0))
    if gap > SPREAD_FRAMES:
        # Solved frames far apart (a long trial): the pose corrections interpolated between them miss the
        # motion in between (30 000 squat frames, 250 apart: a start cost 200 times the final, and the joint
        # solve crawling from it at a large damping).  The poses are fitted to the solved geometry first.
        say(f"solve: every frame's pose fitted to the geometry (the solved frames are up to {gap} frames apart)")
        state, _ = levenberg_marquardt(problem, state, solver, pose_only=True, max_iterations=POSE_ITERATIONS,
                                       progress=_clock(say, problem, solver, "poses, "))
    return levenberg_marquardt(problem, state, solver, progress=progress or _clock(say, problem, solver, label))


LEVEL_GROWTH = 8  # each larger subsample of a long trial: this many times the frames of the last
LEVEL_ROOM = 3  # ... taken while the trial has at least this many times its frames


HIP_FRAMES = 300  # frames of each trial on which the hip centres are compared with Harrington's regression


SPREAD_FRAMES = 50  # solved frames further apart than this (0.5 s at 100 Hz): every frame's pose refitted first
POSE_ITERATIONS = 10  # pose-only iterations of that refit (at most; it stops on the solver's tolerances)


#: A calibration whose every trial's markers place the root in fewer than this share of its frames is refused (the
#: public sweeps' walks in and out of the capture volume: 36-100 % placed; an upper body's trial posing its torso by
#: a sternum and one acromion: 2 %)
ROOT_PLACED_MIN = 0.10
SHOWN_MARKERS = 3  # ... of its frames that show at least this many markers (fewer place no segment)
STILL_MOTION = 0.005  # m: a trial whose markers on different segments move less than this (median SD) is still
# m: ... unless one such pair moves more than this (SD): a joint turns.  arm26's elbow flexion has three markers on
# three segments, two pairs of them across the elbow's axis or on the welded shoulder (0.4, 1.7 mm) and one that
# the flexion moves (58 mm): its median, 1.7 mm, called it still.  The real statics' largest pair: 1.6 (gait2392),
# 4.3 (Hamner), 15 mm (Rajagopal's, whose arms drift).
STILL_PAIR = 0.025


def _still_lengths(trials: Sequence[Trial], motion: Sequence[float], weight: float) -> list[float] | None:
    """What each trial counts as in frames: a still trial (STILL_MOTION) longer than `weight` frames
    as `weight` (PipelineOptions.still_weight), any other as its length; None when `weight` is 0, no trial
    is still or none moves.  A static trial repeats one pose, and with it the pose's errors (skin over a
    bone held still, an acromion marker lifted with the arm): its frames are not independent, and counted
    one by one they outweigh the walk (gait2392's 300 standing frames beside 121 walking; the learnt
    correlation time caps at NOISE_TAU_SECONDS), bending the geometry to the one pose: counted as 16, the
    walks' held-out frames fitted 3-6 mm RMS better on each real recording (docs/benchmarks.md)."""
    still = [m < STILL_MOTION for m in motion]
    if weight <= 0 or not any(still) or all(still):
        return None
    lengths = [min(float(t.n_frames), weight) if s else float(t.n_frames)
               for t, s in zip(trials, still, strict=True)]
    return lengths if any(n < t.n_frames for n, t in zip(lengths, trials, strict=True)) else None


SIZE_RANGE = (0.3, 3.0)  # the subject's size against the base model's beyond which the units are wrong (mm read as m)
COINCIDENT = 0.005  # m: a trial whose model markers all stay this close to their centroid holds no body's markers


def _check_size(model: Model, trials: Sequence[Trial], size) -> None:
    """Refuse trials whose markers put the subject at a size no unit-consistent trial does (SIZE_RANGE times the
    base model's: a subject of 0.5 or 5 m against a 1.7 m model): a trial in mm read as m is 1000 times too large,
    and the calibration would converge to segments scaled to the bound.  The trial to blame is named by its own
    size where the trials differ."""
    lo, hi = SIZE_RANGE
    if size is None:
        # No pair of markers at a steady distance: a trial whose markers all sit at one point (a placeholder, a
        # failed export, every label filled with one value) has none, and would calibrate to a model shrunk to it.
        for t in trials:
            shown = [lab for lab in model.marker_names if lab in t.labels]
            X = t.select(shown).markers if shown else np.zeros((0, 0, 3))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                spread = np.nanmax(np.linalg.norm(X - np.nanmean(X, axis=1, keepdims=True), axis=2), axis=1)
            if len(shown) >= 2 and np.any(np.isfinite(spread)) and np.nanmax(spread) < COINCIDENT:
                raise CalibrateError(
                    f"{t.source or 'the trial'}: its {len(shown)} markers of {model.path.name} sit within "
                    f"{1e3 * np.nanmax(spread):.1f} mm of one point in every frame, as no body's markers do; check "
                    "that the file holds the recorded trajectories (not a placeholder or a failed export)")
        return
    if lo < size.overall < hi:
        return
    own = [(t, size_from_markers(model, [t])) for t in trials] if len(trials) > 1 else [(trials[0], size)]
    t, s = next(((t, s) for t, s in own if s is not None and not lo < s.overall < hi), own[0])
    s = s if s is not None else size
    raise CalibrateError(f"{t.source or 'the trial'}: its markers put the subject at {s.overall:.3g} times the size of "
                         f"{model.path.name} ({s.pairs} marker pairs of steady distance); check the file's units (mm "
                         "read as m makes it 1000 times too large; a C3D's POINT:UNITS, a TRC's Units) or its labels")


RATE_MAX_SPEED = 30.0  # m/s: the median marker's 95th-percentile speed beyond which a trial's frame rate is wrong


def _check_rate(model: Model, trials: Sequence[Trial]) -> None:
    """Refuse a trial whose markers would move faster than any body's at the frame rate it states: the median of its
    model markers' 95th-percentile frame-to-frame speeds above RATE_MAX_SPEED.  On 90 real trials it is at most 5.7
    m/s (a golf swing; a sprinter's whole body moves at 10); a walk read at 10⁶ Hz moves at 8 km/s, and its seed's 6 Hz
    low-pass, its jump and block tests, its noise's correlation time (all in seconds) went wrong without a word
    (pig_walk: 6.0 mm RMS against 3.0)."""
    for t in trials:
        shown = [lab for lab in model.marker_names if lab in t.labels]
        if not shown or t.n_frames < 2:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            speed = np.linalg.norm(np.diff(t.select(shown).markers, axis=0), axis=2) * t.rate
            fast = float(np.nanmedian(np.nanpercentile(speed, 95, axis=0)))
        if fast > RATE_MAX_SPEED:
            raise CalibrateError(
                f"{t.source or 'the trial'}: at the {t.rate:g} frames per second it states, its markers move at "
                f"{fast:.3g} m/s (the median marker's 95th percentile; a sprinter's move at about 10): its frame rate "
                "is wrong; correct it in the file (a C3D's POINT:RATE, a TRC's DataRate) and export it again")


def _check_handedness(model: Model, trials: Sequence[Trial]) -> None:
    """Refuse a trial that is a mirror image of the base model (calibrate.seed.seeding.handedness): left-handed axes or
    one axis negated on export.  A human model fits a mirrored body well enough (pig_walk mirrored: 4.7 mm RMS) by
    turning its segments where no joint should, and only implausible centres would say so."""
    for t, h in zip(trials, handedness(model, trials), strict=True):
        if h is not None and h.mirrored:
            raise CalibrateError(
                f"{t.source or 'the trial'}: its markers are a mirror image of {model.path.name}'s ({h.turned} of "
                f"{h.quadruples} marker quadruples that keep their handedness in every pose of the model turn the "
                "other way): its axes are left-handed or one is negated; negate one axis of the trial (or swap two) "
                "and export it again")


MIXED_SIZE = 1.3  # trials whose markers put the subject at sizes this far apart (ratio) are of different subjects
MIXED_PAIRS = 5  # ... each trial's size read from at least this many marker pairs ...
# ... whose distances vary by less than this fraction over the base model's poses (size_from_markers' model_cv; the
# seed's size keeps its 1 %): video keypoints sit near the joint centres, hip to knee, knee to ankle and elbow to
# wrist 2.6-3.1 % in Pose2Sim's model, and on the 1 % rule a keypoint walk showed 3 pairs, too few to judge.  The check
# is for sizes 30 % apart; the marker sets at hand gain 0-9 pairs at 3 %, their sizes within 2 % (docs/benchmarks.md).
MIXED_MODEL_CV = 0.03


def _check_one_subject(model: Model, trials: Sequence[Trial]) -> None:
    """Refuse trials of different subjects: two trials whose steady marker distances put the subject at sizes
    MIXED_SIZE times apart or more (size_from_markers on each alone, from MIXED_PAIRS pairs or more, of distances
    steady over the base model's poses to MIXED_MODEL_CV).  One subject's trials at hand differ by 0.1-3.0 % (marker
    sets: gait2392, pig_walk, BTKData's four pairs, Pose2Sim's augmented keypoints), by 8.6 % with video keypoints;
    Pose2Sim's demo with one participant's static and the other's trial, 39-58 %, where the fit ended at 91 mm RMS,
    flagging the sacrum."""
    if len(trials) < 2:
        return
    own = [(t, s) for t in trials if (s := size_from_markers(model, [t], model_cv=MIXED_MODEL_CV)) is not None
           and s.pairs >= MIXED_PAIRS]
    if len(own) < 2:
        return
    (small, a), (big, b) = min(own, key=lambda ts: ts[1].overall), max(own, key=lambda ts: ts[1].overall)
    if b.overall < MIXED_SIZE * a.overall:
        return
    raise CalibrateError(f"{big.source or 'a trial'}: its markers put the subject at {b.overall:.2f} times the size of "
                         f"{model.path.name}, {small.source or 'another trial'}'s at {a.overall:.2f} ({b.pairs} and "
                         f"{a.pairs} marker pairs of steady distance): trials of different subjects (or units)? "
                         "calibrate each subject's trials on their own")


APART = 0.10  # two trials whose markers on each segment keep distances this far apart (the median over the pairs of
# |ratio - 1|) are named as two subjects' ...
APART_PAIRS = 10  # ... from this many same-segment pairs or more (50 mm or more apart in the base model)


def trials_apart(model: Model, trials: Sequence[Trial]) -> tuple[tuple[int, int, float, int], ...]:
    """(i, j, misfit, pairs) for each two trials whose markers on one segment of `model` keep distances more than
    APART apart: the median over the pairs (APART_PAIRS or more, each 50 mm or more apart in the base model) of
    |one trial's median distance / the other's - 1|.  A segment's markers keep their distances in any pose, so one
    subject's trials read 0.5-2.3 % with markers (BTKData's Plug-in Gait sessions, pig_walk, OpenSim's gait2392 and
    Rajagopal), 6.5-6.9 % with Pose2Sim's augmented keypoints; two subjects' 11-30 % (BTKData's FlatFoot static with
    another subject's walk: 16 %, under _check_one_subject's 30 %, and the fit put centres 89-163 mm from the scaled
    base model without naming why).  Named, not refused."""
    if len(trials) < 2:
        return ()
    meds = [segment_distances(model, t)[0] for t in trials]
    out = []
    for i in range(len(trials)):
        for j in range(i + 1, len(trials)):
            ok = np.isfinite(meds[i]) & np.isfinite(meds[j]) & (meds[j] > 0)
            if ok.sum() < APART_PAIRS:
                continue
            misfit = float(np.median(np.abs(meds[i][ok] / meds[j][ok] - 1.0)))
            if misfit > APART:
                out.append((i, j, misfit, int(ok.sum())))
    return tuple(out)


#: A label the rigidity test names as riding with another segment (misplaced_labels) stays named only where the fit
#: cannot place it on its own either: its residuals' RMS in that trial over MISPLACED_FIT times the median of the
#: trial's markers', or half its positions rejected.  Distances alone cannot tell a marker on a hinge's axis, or
#: beside a joint the trial hardly turns, from one on the segment across it: a stiff-ankled walk's LHEE (1.9 mm SD to
#: the shank's markers, 5.9 to a toe marker that bends with the forefoot) was named, its residuals 0.19 times the
#: trial's median.  Labels exchanged across segments in simulated walks and squats: 2.3-65 times (5-39 but for a
#: partner named with them).  A clinical lab's RKNE on its knee's axis (1.8 mm SD to the shank's, 6.0 to its thigh
#: wand) fits 1.0 times the median, but 2.1 once Harrington's regression holds its hips: still named.
MISPLACED_FIT = 2.0


def _misfit(misplaced: tuple, residuals: np.ndarray, seen: np.ndarray, spans: Sequence[slice],
            model: Model) -> tuple:
    """The (trial index, Misplaced) entries the fit confirms (MISPLACED_FIT): `residuals` (F, markers, 3) NaN where
    not fitted, `seen` (F, markers) where the trials showed the marker."""
    out = []
    for i, m in misplaced:
        k = model.marker_index(m.label)
        d = np.linalg.norm(residuals[spans[i]], axis=2)
        fitted = np.isfinite(d)
        if not fitted[:, k].any() or 2 * fitted[:, k].sum() < seen[spans[i], k].sum():
            out.append((i, m))
            continue
        shown = fitted.any(axis=0)
        rms = np.sqrt(np.nanmean(np.where(fitted[:, shown], d[:, shown], np.nan) ** 2, axis=0))
        if np.sqrt(np.mean(d[fitted[:, k], k] ** 2)) > MISPLACED_FIT * float(np.median(rms)):
            out.append((i, m))
    return tuple(out)


MISPLACED_MOTION = 3.0  # a trial's labels are judged by rigidity (misplaced_labels) where its markers on different
# segments move this many times as much as those on one segment (median distance SDs, relative_motion against
# segment_jitter): the real moving trials at hand 7-25 with markers, 4.1-9.3 with keypoints and augmented markers;
# Pose2Sim's augmented statics 1.8-2.2, its crouching child's trial 2.9 (docs/benchmarks.md).


def segment_jitter(trial: Trial, model: Model) -> float:
    """How much the trial's markers on one segment of `model` move against each other: the median over such pairs
    of their distance's SD (m; 0 with none).  Skin over a rigid bone: 1-3 mm on the marker sets at hand; video
    keypoints and their augmented markers 2-13 mm."""
    vals = _pair_spreads(trial, model, same=True)
    return float(np.median(vals)) if vals.size else 0.0


def _pair_spreads(trial: Trial, model: Model | None, same: bool = False) -> np.ndarray:
    """The SDs over (at most ~200 of) the trial's frames of its marker pairs' distances (m): pairs on two segments of
    `model` (`same`: on one segment), or without a model every pair of labelled markers."""
    seg = {m.name: m.segment for m in model.markers} if model is not None else None
    labs = [lab for lab in trial.labels if (lab in seg if seg is not None else not UNLABELLED.fullmatch(lab))]
    if not labs:
        return np.zeros(0)
    D = distance_variance(trial.select(labs).markers[:: max(1, trial.n_frames // 200)], min_frames=3)
    apart = ~np.eye(len(labs), dtype=bool)
    if seg is not None:
        on_one = np.array([[seg[a] == seg[b] for b in labs] for a in labs], dtype=bool)
        apart &= on_one if same else ~on_one
    return np.sqrt(D[apart & np.isfinite(D)])


def relative_motion(trial: Trial, model: Model | None = None, percentile: float = 50.0) -> float:
    """How much the trial's markers on different segments of `model` move relative to each other: the median
    over such pairs of their distance's SD (m; a static trial's: 0.4-1.6 mm on the real recordings, their
    walks' 15 mm and more).  Without a model, over every pair of labelled markers (the few on one segment barely
    move the median; the real recordings: statics 0.4-1.6 mm, walks 14-24 mm).  A trial under STILL_MOTION is
    still.  `percentile`: another percentile over the pairs than the median (100: the pair that moves most)."""
    vals = _pair_spreads(trial, model)
    return float(np.percentile(vals, percentile)) if vals.size else 0.0


def _still_only(model: Model, trials: Sequence[Trial], motion: Sequence[float] | None) -> float | None:
    """The largest relative_motion of the trials if every one is still (a static calibrated alone: nothing places the
    joints) and none has a pair of markers on two segments moving more than STILL_PAIR, else None.  `motion`:
    _trial_motion, if measured."""
    if motion is None or len(trials) == 1:
        motion = [relative_motion(t, model) for t in trials]
    if max(motion) >= STILL_MOTION or any(relative_motion(t, model, 100.0) > STILL_PAIR for t in trials):
        return None
    return max(motion)


def _statics_alone(model: Model, trials: Sequence[Trial], motion: Sequence[float] | None = None) -> bool:
    """Whether every trial is still: its markers on different segments keep their distances (relative_motion under
    STILL_MOTION; one pair may move more, as a static's turned head: _still_only is stricter).  `motion`:
    _trial_motion, if measured for more than one trial."""
    if motion is None or len(trials) == 1:
        motion = [relative_motion(t, model) for t in trials]
    return max(motion) < STILL_MOTION


def _still_centres(model: Model, settings: Settings, trials: Sequence[Trial],
                   motion: Sequence[float] | None = None) -> tuple[str, ...]:
    """The ball joints whose centres the trials leave to the priors because none of them moves (statics alone:
    every trial's markers on different segments keep their distances, relative_motion < STILL_MOTION) and no pair
    of markers across the joint (one on its parent segment, one on its child) changes its distance by more than
    STILL_PAIR (SD; BTKData's FlatFoot-Hole static turns its head, not its hips).  Only those with a segment below
    the child that carries a joint of its own (hips, shoulders, lumbar: not the neck, whose head ends the chain),
    not held already and without a joint-centre marker the trials show (--hip-regression's, a lab's R_HJC).
    No joint turns, so each centre's 20 mm prior in its parent's frame trades with the markers around it and the
    segment lengths below: real Plug-in Gait statics put the hips 41-61 mm from Harrington's regression, held at
    the base model's offset from the pelvis markers 10-20 mm (docs/benchmarks.md, "A static alone").  `motion`:
    _trial_motion, if measured."""
    if "centre" not in settings.free or not _statics_alone(model, trials, motion):
        return ()
    parents = {j.parent for j in model.joints}
    labels = {lab for t in trials for lab in t.labels}
    marked = {model.joints[t.joint].name for t in joint_centre_markers(model, model.parameters())
              if model.markers[t.marker].name in labels}
    candidates = [j for j in model.joints if j.kind == "ball" and j.child in parents
                  and j.name not in settings.hold_centres and j.name not in marked]
    seg = {mk.name: mk.segment for mk in model.markers}
    moving: set[str] = set()
    for t in trials:
        labs = [lab for lab in t.labels if lab in seg]
        sd = np.sqrt(distance_variance(t.select(labs).markers[:: max(1, t.n_frames // 200)], min_frames=3))
        for j in candidates:
            a = [i for i, lab in enumerate(labs) if seg[lab] == j.parent]
            b = [i for i, lab in enumerate(labs) if seg[lab] == j.child]
            across = sd[np.ix_(a, b)]
            if np.any(across[np.isfinite(across)] > STILL_PAIR):
                moving.add(j.name)
    return tuple(j.name for j in candidates if j.name not in moving)


def _still_axes(model: Model, settings: Settings, trials: Sequence[Trial],
                motion: Sequence[float] | None = None) -> tuple[str, ...]:
    """The hinge and universal axes the trials leave to the priors because none of them moves (statics alone,
    _statics_alone), not held already.  A static's few degrees of knee flexion, under its skin's sway, turned
    Rajagopal's right knee axis 34 deg from the base model's (its walk then fitted with the shanks 40-70 mm off, 32
    mm RMS against OpenSim's 22 after its Scale); the still test of each coordinate (auto_hold's, after the first
    solve) had let it go, as it had turned more than one frame's markers fix it."""
    if "axis" not in settings.free or not _statics_alone(model, trials, motion):
        return ()
    return tuple(d for j in model.joints if j.kind in ("hinge", "universal") for d in j.dofs
                 if d not in settings.hold_axes)


def _trial_motion(model: Model, trials: Sequence[Trial]) -> list[float]:
    """relative_motion of every trial (one trial: not measured, nothing to compare it with)."""
    return [relative_motion(t, model) for t in trials] if len(trials) > 1 else [0.0]


def _read_as(found: Sequence[ExchangedCluster], obs: np.ndarray, raw: np.ndarray, problem: Problem,
             spans: Sequence[slice]) -> tuple[np.ndarray, np.ndarray, Problem]:
    """The observations (`obs`, `raw` and the problem's) with each exchange of `found` read back in its trial."""
    names = list(problem.model.marker_names)
    return (relabel_columns(obs, spans, found, names), relabel_columns(raw, spans, found, names),
            problem.with_observed(relabel_columns(problem.observed, spans, found, names)))


def _pose_bare(problem: Problem, start: State, obs: np.ndarray, spans: Sequence[slice], bare: Sequence[int],
               trials: Sequence[Trial], params: Parameters) -> State:
    """`start` with the frames of the trials `bare` (their new markers alone) posed by them at `params` (frame-wise IK,
    as the start poses the others), its geometry `params`."""
    evaluator = problem.frame_evaluator(params.vector())
    parts = {k: start_poses(problem.kin, obs[spans[k]], params, key_stride(trials[k].rate), evaluator=evaluator,
                            local=True) for k in bare}
    return replace(stack_states([parts[k] if k in parts else frames_of(start, spans[k]) for k in range(len(spans))]),
                   p=params.vector())


#: m: a relabelling of a cluster between the trials that show the model's markers and the trials of clusters alone is
#: a candidate where it keeps every distance between the cluster's markers (medians over each side's frames) within
#: this of the other side's: a symmetric plate's turns, an asymmetric cluster's true relabelling (skin moves a cluster's
#: markers against each other by a few mm).
BARE_MATCH = 0.010
#: A candidate relabelling is taken where posing the trials of clusters alone with it fits them (the median over their
#: frames of each frame's marker RMS) at most this times as well as with the labels as they are.
BARE_GAIN = 0.5
BARE_FRAMES = 300  # frames of each trial of clusters alone a relabelling is judged on (_bare_exchanges)


def _bare_exchanges(subject: Model, problem: Problem, start: State, obs: np.ndarray, spans: Sequence[slice],
                    bare: Sequence[int], trials: Sequence[Trial], params: Parameters,
                    placed: Sequence[NewMarker]) -> list[ExchangedCluster]:
    """The clusters that the trials showing the model's markers name otherwise than the trials of clusters alone
    (`bare`; `start` poses them at `params`, the clusters' places read from the others).  Their markers' distances to
    each other cannot tell a symmetric plate turned about its symmetry (Expert1's static names its left thigh plate
    turned 180 deg from its walk), and the clusters' places and the bare trials' poses agree with either labelling;
    but the segment posed by a turned plate breaks the chain its neighbours' clusters pose.  So each relabelling that
    keeps the distances (BARE_MATCH; 3 to 6 markers on one segment, shown on both sides) is tried: the bare trials
    posed again with the places exchanged, and the one that fits them best taken where it fits BARE_GAIN times better
    than the labels as they are.  One ExchangedCluster per trial with the model's markers that shows them, read as the
    bare trials name them."""
    from itertools import permutations

    names = list(subject.marker_names)
    posed = [k for k in range(len(spans)) if k not in bare]
    rows_b = np.concatenate([np.arange(spans[k].start, spans[k].stop) for k in bare])
    rows_p = np.concatenate([np.arange(spans[k].start, spans[k].stop) for k in posed])
    new = {m.label for m in placed if m.segment}

    def seen_in(rows: np.ndarray, k: int) -> bool:
        return bool(np.isfinite(obs[rows, k]).all(axis=1).any())

    groups: dict[str, list[int]] = {}
    for k, m in enumerate(subject.markers):
        if m.name in new and seen_in(rows_b, k) and seen_in(rows_p, k):
            groups.setdefault(m.segment, []).append(k)

    def distances(rows: np.ndarray, idx: list[int]) -> np.ndarray:
        X = obs[rows][:, idx]
        return np.nanmedian(np.linalg.norm(X[:, :, None] - X[:, None, :], axis=3), axis=0)

    # Judged on about BARE_FRAMES evenly spaced frames of each bare trial, each posed from the one before (as the
    # start's race poses its subsample): a 6000-frame walk's four posings took 4 s whole.
    rows_s = np.concatenate([np.arange(spans[k].start, spans[k].stop)[:: max(1, (spans[k].stop - spans[k].start)
                                                                           // BARE_FRAMES)] for k in bare])
    sub = Problem(problem.model, obs[rows_s], problem.settings, problem.kin, problem.base)

    def fit(p: Parameters) -> tuple[float, State]:
        st = replace(start_poses(problem.kin, obs[rows_s], p, stride=1, evaluator=sub.frame_evaluator(p.vector()),
                                 local=True), p=p.vector())
        per = np.sqrt(np.nanmean(np.sum(sub.marker_residuals(st) ** 2, axis=2), axis=1))
        return float(np.nanmedian(per)), st

    found = []
    base = None
    for segment, idx in groups.items():
        if not 3 <= len(idx) <= 6:
            continue
        Dp, Db = distances(rows_p, idx), distances(rows_b, idx)
        ident = tuple(range(len(idx)))
        cands = [sg for sg in permutations(ident) if sg != ident
                 and np.nanmax(np.abs(Dp - Db[np.ix_(sg, sg)])) < BARE_MATCH]
        if not cands:
            continue
        base = fit(params)[0] if base is None else base
        tried = {}
        for sg in cands:
            p = params.copy()
            for i, j in enumerate(sg):  # the others' label idx[i] is the bare trials' idx[sg[i]]
                p.marker[idx[j]] = params.marker[idx[i]]
            tried[sg] = (*fit(p), p)
        sg = min(tried, key=lambda x: tried[x][0])
        cost, st, p = tried[sg]
        if cost > BARE_GAIN * base:
            continue
        # Each label's place where the others show it against its place in the bare trials so posed (m)
        columns, _, local, _ = _new_places(subject, problem.kin, st, obs[rows_s], p, placed)
        at = {k: np.nanmedian(local[:, i], axis=0) for i, k in enumerate(columns)}
        scale = params.scale[subject.segment_index(segment)]
        moved = [i for i in ident if sg[i] != i]
        own = tuple(float(np.linalg.norm(scale * params.marker[idx[i]] - at[idx[i]])) for i in moved)
        other = tuple(float(np.linalg.norm(scale * params.marker[idx[i]] - at[idx[sg[i]]])) for i in moved)
        for k in posed:
            if any(names[idx[i]] in trials[k].labels for i in moved):
                found.append(ExchangedCluster(k, segment, tuple(names[idx[i]] for i in moved),
                                              tuple(names[idx[sg[i]]] for i in moved), own, other))
    return found


def _without_trials(obs: np.ndarray, spans: Sequence[slice], trials: Sequence[int]) -> np.ndarray:
    """`obs` (frames, markers, 3) with the frames of `trials` (indices into `spans`) unseen (NaN)."""
    if not trials:
        return obs
    out = obs.copy()
    for k in trials:
        out[spans[k]] = np.nan
    return out


#: Provisional places (m, in the segment's frame) of declared labels not yet placed, for judging what they pose: apart
#: from each other and from the origin, no three on a line through it.
PROVISIONAL = np.array([[0.10, 0.04, 0.02], [-0.03, 0.10, 0.05], [0.02, -0.05, 0.10], [-0.07, -0.06, -0.04]])


def _provisional(k: int) -> np.ndarray:
    """The k-th declared label's provisional place (PROVISIONAL, each round of four a tenth further out)."""
    return PROVISIONAL[k % len(PROVISIONAL)] * (1.0 + 0.1 * (k // len(PROVISIONAL)))


def _declared_unplaced(model: Model, new: Mapping[str, str], waiting: Sequence[str]) -> str:
    """Part of the refusals above, where the marker map's [segments] put labels (`waiting`, of `new`: label ->
    segment) on segments that no trial's model markers pose: those labels take their places from such a trial (a
    cluster's place on its segment read where the anatomical landmarks show the segment), so they place nothing
    here; what would place them."""
    if not waiting:
        return ""
    segments = list(dict.fromkeys(new[lab] for lab in waiting))
    return (f"; the {len(waiting)} labels the marker map's [segments] puts on {', '.join(segments)} take their places "
            f"from a trial whose model markers pose their segments, and no trial here does: add a static that shows "
            f"those segments' model markers beside the clusters (`calibrate inspect {model.path.name}` lists them)")


def _members(model: Model, declared: Mapping[str, str]) -> Model:
    """`model` with the declared labels (the marker map's [segments]) as markers of their segments, at the segments'
    origins: for what reads only which segment a label rides on (relative_motion), never for a place."""
    return add_markers(model, {lab: (seg, np.zeros(3)) for lab, seg in declared.items()
                               if lab not in model.marker_names}) if declared else model


def _bare_trials(model: Model, trials: Sequence[Trial], declared: Mapping[str, str]) -> list[int]:
    """The trials that show none of `model`'s markers in any frame, each showing three or more labels the marker map's
    [segments] declares (a CAST protocol's walk, its clusters alone); CalibrateError (one line) for one that does not,
    or where every trial is so."""
    known = set(model.marker_names)

    def shown(t: Trial, lab: str) -> bool:
        return lab in t.labels and bool(np.isfinite(t.marker(lab)).any())

    bare = [i for i, t in enumerate(trials) if not any(shown(t, lab) for lab in t.labels if lab in known)]
    for i in bare:
        t = trials[i]
        mine = [lab for lab in t.labels if not UNLABELLED.fullmatch(lab)]
        # (its labels' places are read where the other trials show them with the model's markers)
        said = [lab for lab in mine if lab in declared and shown(t, lab)
                and any(shown(u, lab) for k, u in enumerate(trials) if k not in bare)]
        if len(said) < 3 or len(bare) == len(trials):
            why = ("and neither does any other trial" if len(bare) == len(trials) else
                   f"and {len(said)} of its labels are both under the marker map's [segments] and shown by a trial "
                   "that shows the model's markers (3 or more pose it)")
            raise CalibrateError(
                f"{t.source or 'a trial'}: shows none of {model.path.name}'s markers in any frame (its labels: "
                f"{', '.join(mine[:4])}{', ...' if len(mine) > 4 else ''}) {why}; list its clusters' labels under "
                f"their segments in the marker map's [segments] (--markers map.toml) beside a trial that shows the "
                f"model's markers and the clusters (a static), or pose it on a calibrated subject: calibrate ik TRIAL "
                f"SUBJECT.urdf")
    return bare


def _declared_doubts(model: Model, trials: Sequence[Trial], declared: Mapping[str, str],
                     motion: Sequence[float]) -> dict[str, str]:
    """Label -> why to check it, for each label of the marker map's ``[segments]`` whose place, on the base model's
    poses of the trials that move, spreads more than 1 / HOST_RATIO times as much on the declared segment as on
    another (hosts.place_spreads, kinematic_hosts' measure); none where no trial moves (nothing can tell)."""
    from .hosts import HOST_RATIO, place_spreads

    moving = [t for t, a in zip(trials, motion, strict=True) if a >= STILL_MOTION] if len(trials) > 1 else \
        [t for t in trials if relative_motion(t, model) >= STILL_MOTION]
    shown = [lab for lab in declared if any(lab in t.labels for t in moving)]
    if not shown:
        return {}
    out = {}
    for lab, spread in place_spreads(model, moving, shown, sorted(set(declared.values()))).items():
        best = min(spread, key=spread.get)
        own = spread[declared[lab]]
        if best != declared[lab] and spread[best] < HOST_RATIO * own:
            out[lab] = (f"on the base model's poses its place spreads {1e3 * spread[best]:.1f} mm RMS on {best}, "
                        f"{1e3 * own:.1f} on {declared[lab]}: does it ride on {best}?")
    return out


def _assign_new_markers(model: Model, trials: Sequence[Trial], unknown: list[str],
                        motion: Sequence[float], declared: Mapping[str, str] | None = None,
                        bare: Sequence[int] = ()) -> list[NewMarker]:
    """Segments for the trial markers the model does not know (seed 002's rigidity, against the
    model's known markers: calibrate.seed.association.associate_to_model over the trials' frames).
    Rigidity is judged on the trials that move (STILL_MOTION), if any: in a static trial every marker
    keeps its distance to every other, so its frames would pass any marker as rigid with any segment
    and set the rigidity threshold at the static's noise (gait2392: 0.2 mm, its walk's 1.1 mm; pig_walk's
    thigh marker then came out closer to the right femur than to the left).  `motion`: _trial_motion.
    `declared`: label -> segment, the marker map's ``[segments]``: the user's word, taken without the tests (in a
    static alone too, where no test can tell).  `bare`: the trials that show none of the model's markers
    (_bare_trials), which nothing poses before the new labels are placed: judged without them, and a label only they
    show left out."""
    declared = {lab: seg for lab, seg in (declared or {}).items() if lab in unknown}
    if bare:  # (the tests pose the trials by the model's markers: those that show none are judged without them)
        keep = [i for i in range(len(trials)) if i not in bare]
        shown = {lab for i in keep for lab in trials[i].labels}
        found = {m.label: m for m in _assign_new_markers(
            model, [trials[i] for i in keep], [lab for lab in unknown if lab in shown], [motion[i] for i in keep],
            declared)}
        return [found.get(lab) or NewMarker(lab, None, None, "seen only in trials that show none of the model's "
                                                            "markers, where nothing poses it") for lab in unknown]
    if declared:
        # The others judged as without the map (with the declared among them: the rigidity test's threshold is set by
        # the trial's most rigid pairs, new labels' too, and PlugInC3D's sacral marker, at that threshold, had gone out
        # when its thigh wands were declared): declaring a label changes that label only.
        by = {m.label: m for m in _assign_new_markers(model, trials, unknown, motion)}
        doubts = _declared_doubts(model, trials, declared, motion)
        return [NewMarker(lab, declared[lab], None, f"the marker map's [segments] puts it on {declared[lab]}",
                          check=doubts.get(lab, ""), declared=True) if lab in declared else by[lab] for lab in unknown]
    moving = [i for i, a in enumerate(motion) if a >= STILL_MOTION] if len(trials) > 1 else [0]
    if _statics_alone(model, trials, motion if len(trials) > 1 else None):
        # No trial moves: every marker keeps its distance to every other and every segment's pose is as still as the
        # next one's, so neither rigidity nor the poses say where a label rides (kineticstoolkit's wheelchair-racing
        # static had put its arm, forearm and glove markers on the femurs, its wheelchair's on the torso).
        names = ", ".join(Path(t.source).name if t.source else f"trial {i + 1}" for i, t in enumerate(trials))
        return [_medial(model, lab, "seen only in still trials")
                or NewMarker(lab, None, None, f"seen only in still trials ({names}): no motion shows which segment "
                                              "it rides on") for lab in unknown]
    used = [trials[i] for i in (moving or range(len(trials)))]
    labels = (*model.marker_names, *unknown)
    together = Trial(labels, np.concatenate([t.columns(labels) for t in used]), used[0].rate)
    assoc = associate_to_model(model, together)
    # Those rigidity leaves out, judged again on the model's own poses (calibrate.calibration.hosts): a cluster on
    # skin, or a segment whose one known marker sits near a joint.
    # A medial epicondyle or malleolus marker lies on its hinge's axis: it keeps its distances to the markers on both
    # sides of the hinge however the joint turns, and its place in either segment's frame as well, so neither rigidity
    # nor the poses tell the segment above from the one below (OpenCap's walk: R_elbow_med on the radius by its wrist
    # markers, 11 mm against the humerus's 28; Expert1's left on neither).  Its name decides, as in a still trial.
    medial = {lab for lab in unknown if medial_host(model, lab) is not None}
    left = [lab for lab in unknown if assoc[lab].segment is None and lab not in medial
            and any(lab in t.labels for t in used)]
    # (the host tests below pose the base model on the same frames: each fit made once)
    base_poses = BasePoses()
    hosts = kinematic_hosts(model, used, left, cache=base_poses) if left else {}
    # Those left still, by their distances' margins (association.margin_hosts): a segment whose own markers move
    # against each other on skin more than the trial's rigidity threshold (a two-marker foot, a pelvis), which the
    # poses cannot pin either (a foot posed by its heel and toe turns about the line between them).
    rest = [lab for lab in left if lab not in hosts or hosts[lab].segment is None]
    placed = {lab: seg for lab in unknown
              if lab not in medial and (seg := hosts[lab].segment if lab in hosts else assoc[lab].segment) is not None}
    margins = margin_hosts(model, together, rest, placed) if rest else {}
    # And a rigid cluster of those still left, by a segment whose model markers the trials never show (a head band
    # the model spells otherwise: calibrate.calibration.hosts.cluster_hosts).
    rest = [lab for lab in rest if lab not in margins or margins[lab].segment is None]
    clusters = cluster_hosts(model, used, rest, assoc.threshold) if rest else {}
    # Any of them placed on a segment's near side that sits by the base model's markers of a segment below it which
    # no known marker moves (hosts.past_joints: a wrist marker on a humerus where the elbow has no known marker)
    placed.update({lab: margins[lab].segment for lab in margins if margins[lab].segment is not None})
    past = past_joints(model, used, placed, cache=base_poses) if placed else {}
    # And a rigid cluster still left that turns about a joint of a posed segment, on the segment beyond that joint the
    # markers do not pose (hosts.joint_hosts: gait2392's thigh and shank plates, its knee and ankle markers in the
    # static alone).  Judged by past_joints too: an arm whose elbow a walk barely turns keeps its upper-arm, forearm
    # and hand markers within 1-2.5 mm of each other and turns about the shoulder as one (pig_walk on Rajagopal2016,
    # LUPA, LFRM and LFIN on humerus_l): those past the joints below no known marker moves sit by the base model's
    # markers there.
    rest = [lab for lab in rest if lab not in clusters or clusters[lab].segment is None]
    joints = joint_hosts(model, used, rest, {**{lab: seg for lab, seg in placed.items() if lab not in past},
                                             **{lab: c.segment for lab, c in clusters.items() if c.segment}}
                         ) if rest else {}
    by_turn = {lab: h.segment for lab, h in joints.items() if h.segment is not None}
    past.update(past_joints(model, used, by_turn, cache=base_poses) if by_turn else {})
    described = described_labels(trials)
    out = []
    for lab in unknown:
        if lab in medial:
            shown = any(lab in t.labels for t in used)
            out.append(_medial(model, lab, "on its hinge's axis, where neither its distances nor its places tell the "
                                           "segments apart" if shown else "seen only in still trials"))
        elif lab in past:
            out.append(NewMarker(lab, None, None, past[lab].reason(), sits_by=past[lab].near))
        elif len(used) < len(trials) and not any(lab in t.labels for t in used):
            still = ", ".join(Path(t.source).name if t.source else f"trial {i + 1}"
                              for i, t in enumerate(trials) if i not in moving)
            out.append(NewMarker(lab, None, None, f"seen only in still trials ({still}): no motion shows which "
                                                  "segment it rides on"))
        elif lab in hosts and hosts[lab].segment is not None:
            out.append(NewMarker(lab, hosts[lab].segment, None, hosts[lab].reason()))
        elif lab in margins and margins[lab].segment is not None:
            out.append(NewMarker(lab, margins[lab].segment, None, margins[lab].reason()))
        elif lab in clusters and clusters[lab].segment is not None:
            # (its place kept, about the segment's model markers: a segment with no other marker is resolved by where
            # its markers are, and the start places them again)
            c = clusters[lab]
            out.append(NewMarker(lab, c.segment, c.places[c.labels.index(lab)], c.reason(lab)))
        elif lab in joints and joints[lab].segment is not None:
            out.append(NewMarker(lab, joints[lab].segment, None, joints[lab].reason(lab)))
        elif assoc[lab].segment is None and lab in hosts and hosts[lab].axial <= AXIAL_SPREAD \
                and named_kind(lab, described.get(lab)) in NAMED_SEGMENTS \
                and hosts[lab].best in named_segments(model, lab, described.get(lab)):
            # A Plug-in Gait wand whose place spreads least on the segment its name says, though more than a host's,
            # for the loose turn of that segment about its long axis in the model's poses (a thigh posed by its knee
            # marker alone): about that axis it spreads as a host's would (hosts.axial_spread).  PlugInC3D's LTHI on
            # Rajagopal2016.osim: 38.6 mm on femur_l, 51 on tibia_l, about the femur's axis 19; left out, its hips
            # ended 86 mm apart.  The data and the name agree, as the marker map's [segments] would say.
            h = hosts[lab]
            out.append(NewMarker(lab, h.best, None, f"{h.reason()}; about its long axis {1e3 * h.axial:.1f} mm, and "
                                                    f"its name says the {named_kind(lab, described.get(lab))}, "
                                                    "which decides"))
        else:
            # (judged on the poses too, where markerless segments that turn were candidates: the rigidity test's
            # clause that they cannot receive markers no longer holds)
            why = f"{split_reason(assoc[lab].reason)[0]}; {hosts[lab].reason()}" if lab in hosts else assoc[lab].reason
            if lab in joints:
                why += f"; {joints[lab].reason(lab)}"
            out.append(NewMarker(lab, assoc[lab].segment, None, why))
    # Those put on a segment that sit, a rigid cluster of them, beyond the joint of a child no marker poses (a lower-
    # limb marker set's torso: hosts.beyond_joints): on that child, the others there with them or left out.
    tested = {m.label: m.segment for m in out if m.segment is not None and m.position is None and not m.hinge}
    beyond = beyond_joints(model, used, tested, cache=base_poses) if tested else {}
    out = [NewMarker(m.label, b.segment, b.place, b.reason(), past=b.segment or "") if (b := beyond.get(m.label))
           else m for m in out]
    return [_off_its_joint(model, m) for m in out]


def _off_line(trials: Sequence[Trial], labels: Sequence[str], frames: int = 50) -> bool:
    """Whether the trials show `labels` (the root's markers) off one line: in the frames that show all of them (about
    `frames`, evenly spaced over the trials), the median of the largest distance of any from their best line exceeds
    resolve.ON_LINE."""
    from ..model.resolve import ON_LINE

    if len(labels) < 3:
        return False
    offs = []
    for t in trials:
        if not all(lab in t.labels for lab in labels):
            continue
        X = t.select(list(labels)).markers
        X = X[np.all(np.isfinite(X), axis=(1, 2))]
        for pts in X[:: max(1, len(X) // frames)]:
            d = pts - pts.mean(axis=0)
            u = np.linalg.svd(d)[2][0]
            offs.append(float(np.linalg.norm(d - np.outer(d @ u, u), axis=1).max()))
    return bool(offs) and float(np.median(offs)) > ON_LINE


def _off_its_joint(model: Model, marker: NewMarker) -> NewMarker:
    """`marker` left out where its name says a joint's centre (hosts.centre_segments: R_HJC) and a test put it on
    neither of that joint's segments (a walk's trunk turns little over the pelvis: Expert1's L_HJC by its distances
    rode as well with C7 and the acromion as with the pelvis markers)."""
    joint = centre_segments(model, marker.label) if marker.segment is not None else None
    if joint is None or marker.segment in joint:
        return marker
    return NewMarker(marker.label, None, None, f"named as the centre of the joint between {joint[0]} and {joint[1]}, "
                                               f"yet placed on {marker.segment} ({marker.reason}): on neither")


def _medial(model: Model, label: str, why: str) -> NewMarker | None:
    """A label placed by its name where it is a medial marker's (hosts.medial_host: r_mknee on the femur the right
    knee hangs from), or None; `why` the name decides (a still trial's alone, or its place on the axis)."""
    host = medial_host(model, label)
    if host is None:
        return None
    return NewMarker(label, host[0], None, f"named as a medial marker of {host[1]} (its epicondyle or malleolus), "
                                           f"{why}: on the segment that joint hangs from", hinge=host[1])


def _protocol_places(subject: Model, params: Parameters, pairs: Sequence[tuple[str, str]]) -> Parameters:
    """`params` with each pair of labels (both on one segment) placed where the base model has the other: a lab's
    protocol that puts them so (association.Exchanged.protocol).  A marker the seed placed where the trial shows it
    (seeding: within SEED_MAX_SHIFT of its base place, so only where the two places are that close) stays there."""
    if not pairs:
        return params
    base = subject.parameters().marker
    marker = params.marker.copy()
    for a, b in pairs:
        i, j = subject.marker_index(a), subject.marker_index(b)
        for k, other in ((i, j), (j, i)):
            if np.array_equal(params.marker[k], base[k]):
                marker[k] = base[other]
    return Parameters(params.scale, params.centre, params.axis, marker)


def _unseen_at_base(subject: Model, model: Model, params: Parameters, unseen: Sequence[str]) -> Parameters:
    """`params` with the markers no frame shows at the base model's offsets, where the problem holds
    them (Problem.unseen): nothing in the data places them."""
    if not unseen:
        return params
    marker, base = params.marker.copy(), model.parameters().marker
    for name in unseen:
        marker[subject.marker_index(name)] = base[model.marker_index(name)]
    return Parameters(params.scale, params.centre, params.axis, marker)


def _on_model(subject: Model, model: Model, params: Parameters) -> Parameters:
    """`params` of `model` on `subject` (the model with new markers, zero offsets for those)."""
    if subject is model:
        return params
    marker = np.zeros((len(subject.markers), 3))
    for k, name in enumerate(subject.marker_names):
        if name in model.marker_names:
            marker[k] = params.marker[model.marker_index(name)]
    return Parameters(params.scale.copy(), params.centre.copy(), params.axis.copy(), marker)


def _new_places(subject: Model, kin: Kinematics, start: State, obs: np.ndarray, params: Parameters,
                placed: list[NewMarker]) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray]:
    """Where the start poses put each placed new marker on its segment: (its index in the model, the frames read,
    local (frames, new, 3): the marker in its segment's frame, m, NaN where not seen; its segment's scale)."""
    new = [k for k, n in enumerate(subject.marker_names) if n in {m.label for m in placed if m.segment}]
    seen = np.all(np.isfinite(obs[:, new]), axis=2)
    # Up to about 100 frames per marker, wherever in the trials it is seen (some are seen briefly).
    frames = np.unique(np.concatenate([np.flatnonzero(seen[:, i])[:: max(1, int(seen[:, i].sum()) // 100)]
                                       for i in range(len(new))]))
    s = np.array([params.scale[subject.segment_index(subject.markers[k].segment)] for k in new])
    if not frames.size:  # every position of them left out (jumps, jitter): nothing places them
        return new, frames, np.full((0, len(new), 3), np.nan), s
    Z, Q = absolute(kin, frames_of(start, frames))
    origin, R = segment_axes(kin, Z, Q, params, new)
    local = np.einsum("fnij,fni->fnj", R, obs[frames][:, new] - origin)
    return new, frames, local, s


def _place_new_markers(subject: Model, places: tuple[list[int], np.ndarray, np.ndarray, np.ndarray],
                       params: Parameters, placed: list[NewMarker],
                       fixed: Mapping[int, tuple[np.ndarray, str]] | None = None
                       ) -> tuple[Parameters, Parameters, list[NewMarker]]:
    """Each new marker's position on its segment from the start poses (`places`: _new_places; seed 002's closed
    form: the median over frames of the marker in the segment's frame), or where `fixed` puts it (marker index ->
    (unscaled offset, why): _far_sacral); these positions are also the centre of its prior.  Returns the start
    parameters, the prior's base parameters and the placements."""
    new, frames, local, s = places
    fixed = fixed or {}
    out = params.copy()
    base = subject.parameters()
    by_label = {m.label: m for m in placed}
    for i, k in enumerate(new):
        use = np.isfinite(local[:, i, 0])
        name = subject.marker_names[k]
        # (none seen: every position of it left out as jumps or jitter; the segment's origin, which no residual reads)
        offset = np.median(local[use, i], axis=0) / s[i] if use.any() else np.zeros(3)
        m = by_label[name]
        across = _across_hinge(subject, out, m.hinge, offset) if m.hinge and k not in fixed else None
        reason = m.reason
        if across is not None:
            offset, lateral, off = across
            reason += (f"; placed across {m.hinge}'s axis from {lateral}, where the start's poses put it "
                       f"{1e3 * off * s[i]:.0f} mm from there, off the line of the two")
        if k in fixed:
            offset, why = fixed[k]
            reason += f"; {why}"
        out.marker[k] = offset
        base.marker[k] = offset
        by_label[name] = replace(m, position=s[i] * offset, reason=reason)
    result = [by_label[m.label] for m in placed]
    return out, base, result


#: m: a new sacral marker the start's poses put this far from the midpoint of the model's spine markers (two prior SDs
#: of a marker's place) is placed there and the start posed again (_far_sacral).  gait2392's trials: 23 mm on
#: models/human.urdf, 61 mm on Rajagopal2016.osim (its pelvis then 1 deg from the lab's IK in tilt, 18 deg without).
SACRAL_APART = 0.040


def _far_sacral(places: tuple[list[int], np.ndarray, np.ndarray, np.ndarray],
                sacral: Mapping[int, tuple[np.ndarray, str]]) -> dict[int, tuple[np.ndarray, str]]:
    """Those of `sacral` (_sacral_places) the start's poses (`places`: _new_places) put more than SACRAL_APART from
    their place there (median over the frames, at the segment's scale), the distance added to the reason."""
    new, _, local, s = places
    out = {}
    for i, k in enumerate(new):
        if k in sacral and (use := np.isfinite(local[:, i, 0])).any():
            offset, why = sacral[k]
            apart = float(np.linalg.norm(np.median(local[use, i], axis=0) - s[i] * offset))
            if apart > SACRAL_APART:
                out[k] = (offset, f"{why} (the start's poses, which it then joined, had put it {1e3 * apart:.0f} mm "
                                  "from there)")
    return out


def _sacral_places(subject: Model, params: Parameters, placed: Sequence[NewMarker], observed: np.ndarray,
                   described: Mapping[str, str] | None = None, measured: np.ndarray | None = None
                   ) -> dict[int, tuple[np.ndarray, str]]:
    """Where the model's posterior superior iliac spine markers put a new sacral marker (Plug-in Gait's SACR:
    V.Sacral, S2): midway between them, as Plug-in Gait defines it, on a segment that carries both and of whose known
    markers the trials show fewer than three (unscaled offsets, by marker index, with the reason; `observed`: the known
    markers' positions, (frames, markers, 3)).  With `measured` (every marker's positions, the new ones' too) and an
    ASIS pair on the model, at the trials' own distance from the ASIS markers' midpoint, in the direction of the
    spines' midpoint: c3d.org's sample10 has its VSAC 265 mm behind the ASIS markers' midpoint where the model's
    spines would put it 166 mm (on Rajagopal2016.osim at the width's scale), which the pelvis's scale had taken up
    (x1.22 against the limbs' 0.93).  A pelvis posed by its two ASIS markers turns freely about their line in
    the start's poses, which may then put the sacral marker anywhere on a circle about it: gait2392's static and walk
    on Rajagopal2016.osim placed its V.Sacral 140 mm RMS apart over the start's frames, and the median's place held the
    pelvis tilted 50 deg back, the hips flexed to match.  A label is read by its name, else by the trials' description
    of it (`described`: c3d.org's sample10 calls V.Sacral VSAC, which on Rajagopal2016.osim had left the pelvis
    tilted the same way, the hips 130-140 mm from the scaled model's)."""
    out: dict[int, tuple[np.ndarray, str]] = {}
    seen = np.all(np.isfinite(observed), axis=2).any(axis=0)
    described = described or {}
    for m in placed:
        if m.segment is None or "SACR" not in (plug_in_gait_name(m.label),
                                                plug_in_gait_name(described.get(m.label, ""))):
            continue
        mine = [k for k, mk in enumerate(subject.markers) if mk.segment == m.segment]
        spines = {plug_in_gait_name(subject.marker_names[k]): k for k in mine
                  if plug_in_gait_name(subject.marker_names[k]) in ("RPSI", "LPSI")}
        if len(spines) < 2 or sum(bool(seen[k]) for k in mine) >= 3:
            continue
        a, b = (spines[n] for n in ("RPSI", "LPSI"))
        k = subject.marker_index(m.label)
        place = 0.5 * (params.marker[a] + params.marker[b])
        how = "midway between"
        depth = _sacral_depth(subject, mine, k, measured) if measured is not None else None
        if depth is not None:
            # at the trials' distance from the ASIS markers' midpoint, toward the model's spines' midpoint
            distance, (r, l) = depth
            front = 0.5 * (params.marker[r] + params.marker[l])
            towards = (place - front) / np.linalg.norm(place - front)
            place = front + towards * distance / float(params.scale[subject.segment_index(m.segment)])
            how = (f"{1e3 * distance:.0f} mm behind the ASIS markers' midpoint (as the trials put it), toward midway "
                   "between")
        out[k] = (place, f"placed {how} the model's {subject.marker_names[a]} and {subject.marker_names[b]} "
                         f"(Plug-in Gait's sacral marker): the trials show fewer than three of {m.segment}'s other "
                         "markers, about which the start's poses may turn it freely")
    return out


def _sacral_depth(subject: Model, mine: Sequence[int], sacral: int, measured: np.ndarray
                  ) -> tuple[float, tuple[int, int]] | None:
    """The trials' median distance (m) from the midpoint of the ASIS markers of `mine` (the segment's markers) to the
    sacral marker, and those markers' indices (right, left); None where the model has no ASIS pair or the trials show
    no frame with all three."""
    asis = {plug_in_gait_name(subject.marker_names[k]): k for k in mine
            if plug_in_gait_name(subject.marker_names[k]) in ("RASI", "LASI")}
    if len(asis) < 2:
        return None
    r, l = asis["RASI"], asis["LASI"]
    d = np.linalg.norm(measured[:, sacral] - 0.5 * (measured[:, r] + measured[:, l]), axis=1)
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return None
    return float(np.median(d)), (r, l)


def _across_hinge(subject: Model, params: Parameters, hinge: str, place: np.ndarray
                  ) -> tuple[np.ndarray, str, float] | None:
    """A hinge's medial marker's place on the segment it hangs from (`place`, unscaled, as the start's poses put it)
    where that place and the hinge's Plug-in Gait lateral marker do not straddle its centre along its axis
    (priors.straddle): the lateral marker's place mirrored across the plane through the centre normal to the axis (or,
    where the start leaves the lateral marker so far off the axis's line that its mirror would pass as far from the
    centre, the point on that line as far across the centre: Expert1's RELB on models/human_girdle.urdf, the medial
    one 144 mm from the mirror, kept there, ended 75 mm from its prior), the lateral marker's name, and how far the
    new place is from `place` (unscaled); None where they straddle already, the model has no lateral marker there,
    or neither would straddle.  A humerus posed by two lateral markers turns freely about their line: the start can
    leave the medial epicondyle 90 mm behind it (AddBiomechanics' Expert1 on models/human.urdf), where the name says
    it is across the elbow from the lateral."""
    lateral = dict(lateral_markers_of(subject)).get(hinge)
    if lateral is None:
        return None
    ji = subject.joint_index(hinge)
    joint = subject.joints[ji]
    axis = hinge_axis(subject, params, subject.dof_index(joint.dofs[0]))
    c, x = params.centre[ji], params.marker[subject.marker_index(lateral)]
    scale = float(params.scale[subject.segment_index(joint.parent)])
    if straddle(scale * c, axis, scale * x, scale * place) is not None:
        return None
    along = float((x - c) @ axis)
    for mirrored in (x - 2.0 * along * axis, c - along * axis):
        if straddle(scale * c, axis, scale * x, scale * mirrored) is not None:
            return mirrored, lateral, float(np.linalg.norm(mirrored - place))
    return None


def _solve_geometry(problem: Problem, state: State, options: SolverOptions,
                    say: Callable[[str], None], polish: bool = True) -> tuple[State, SolverSummary]:
    """Poses, then poses and geometry together, then the segment frames turned to where the
    priors want them and (`polish`) a last run from there: the whole solve on the frames of `problem`
    (the solver's `options`)."""
    say(f"solve: refine poses ({problem.F} frames)")
    state, _ = levenberg_marquardt(problem, state, options, pose_only=True, max_iterations=2)
    if problem.loss != "linear":
        # A robust loss is not convex: reach its basin with plain least squares first.
        say("solve: least squares before the robust loss")
        state, _ = levenberg_marquardt(problem.with_loss("linear"), state, options, max_iterations=30)
    say(f"solve: global Levenberg-Marquardt ({problem.F} frames)")
    state, summary = levenberg_marquardt(
        problem, state, options,
        progress=lambda it, c, lam: say(f"solve: iteration {it:3d}  cost {c:.6e}  lambda {lam:.1e}"))
    say("solve: align segment frames with the base model (gauge)")
    state = align_gauge(problem, state, options)
    if not polish:
        return state, summary
    state, polished = levenberg_marquardt(problem, state, options)
    return state, _merge(summary, polished)


_SUMMED = ("iterations", "accepted", "seconds", "linearize_seconds", "linear_solver_seconds", "evaluate_seconds",
           "bent")


_FROM_FIRST = ("initial_cost", "coarse", "coarse_frames", "levels")  # the start, and any subsample solve before it


_FROM_SECOND = ("final_cost", "termination", "converged")  # the end


def merge_summaries(a: SolverSummary, b: SolverSummary) -> SolverSummary:
    """One summary for two consecutive solver runs: counts and times added, the cost histories joined,
    the start from the first run, the end from the second; any other field as a fresh summary has it."""
    parts = {"cost_history": a.cost_history + b.cost_history[1:]}
    for f in fields(SolverSummary):
        if f.name in _SUMMED:
            parts[f.name] = getattr(a, f.name) + getattr(b, f.name)
        elif f.name in _FROM_FIRST:
            parts[f.name] = getattr(a, f.name)
        elif f.name in _FROM_SECOND:
            parts[f.name] = getattr(b, f.name)
    return SolverSummary(**parts)


_merge = merge_summaries  # the name the solve steps call


def _clock(say: Callable[[str | Progress], None], problem: Problem, solver: SolverOptions,
           label: str) -> IterationClock | None:
    """Iteration lines with the time left for a solve on a long trial (one whose frame blocks do not all
    fit in the memory budget: its iterations take seconds); None (silent) on a shorter one."""
    fits = problem.F * frame_bytes(problem, True) <= problem.settings.memory_mb * 1e6
    return None if fits else IterationClock(say, label, solver.atol, solver.ftol)


def _hips_auto(model: Model, trials: tuple[Trial, ...], settings: Settings, given: dict) -> Calibration:
    """Settings.hip_regression "auto" or "outside" (the default): the calibration without Harrington's regression,
    and where it leaves the hips so, the calibration again with it.  "auto": a hip implausible (HipMotion.implausible:
    the trials' motion does not place it, and it ended further than REGRESSION_FAR from the regression or the hips
    wider apart than HIP_WIDTH_FAR times the ASIS markers; BTKData's Plug-in Gait walks: 46-93 mm, the hips outside
    the ASIS; or, wherever, wider apart than the ASIS markers or closer together than half their width).  "outside":
    only the last, the hips wider apart than the ASIS markers or on the pelvis's midline (HipMotion.nowhere), where no
    hip is, whatever the markers say: BTKData's Plug-in Gait walks and Camargo's level-ground walk ended wider,
    BTKData's 561xxa01 on Rajagopal2016.osim 29 mm apart (docs/benchmarks.md).  The result says which
    (Calibration.hip_regression_auto); where the regression cannot run (regression_hips refuses: the model already
    carries its markers' names, or the pelvis markers are missing), or ("auto") where it makes the markers fit more
    than HIP_AUTO_COST times worse (RMS) and the hips without it lie inside the pelvis (the markers place them against
    it: AddBiomechanics' treadmill walk, OpenCap's squats), the first is kept and says why.  Costs a second
    calibration only where the check fires (the check itself reads the pelvis landmarks the regression needs)."""
    mode = settings.hip_regression
    say = _announcer(given["progress"])
    first = calibrate(model, trials, replace(settings, hip_regression=False), **given)
    tied = {m.joint for m in first.joint_markers}
    far = [h for h in first.hip_motion if (h.implausible if mode == "auto" else h.nowhere) and h.joint not in tied]
    if not far:
        return replace(first, settings=replace(first.settings, hip_regression=mode))
    width, asis = far[0].width
    why = (" and ".join(f"{h.joint} {1e3 * h.from_regression:.0f} mm" for h in far)
           + f" from Harrington's regression on the pelvis markers, the hips {1e3 * width:.0f} mm apart where the "
           f"ASIS markers are {1e3 * asis:.0f}")
    say(Progress("hips", f"{why} without the regression: calibrating again with it (hip_regression {mode})"))
    try:
        second = calibrate(model, trials, replace(settings, hip_regression=True), **given)
    except CalibrateError as e:
        if not str(e).startswith("hip_regression:"):
            raise
        return replace(first, settings=replace(first.settings, hip_regression=mode),
                       hip_regression_auto=f"not applied: {why}, but {str(e).removeprefix('hip_regression: ')}")
    cost = second.marker_rms / first.marker_rms
    if cost > regression.HIP_AUTO_COST and not any(h.nowhere for h in far):
        # The markers place the hips against the regression, and they lie inside the pelvis: the trials' own kept.
        return replace(first, settings=replace(first.settings, hip_regression=mode),
                       hip_regression_auto=f"not applied: {why}, but with it the markers fit {cost:.2f} times worse "
                       f"(RMS {1e3 * first.marker_rms:.2f} -> {1e3 * second.marker_rms:.2f} mm, over "
                       f"{regression.HIP_AUTO_COST:g} times): the trials' own hips kept",
                       times={**first.times, "regressed": sum(second.times.values())})
    return replace(second, settings=replace(second.settings, hip_regression=mode),
                   hip_regression_auto=f"applied: without it {why} (marker RMS {1e3 * first.marker_rms:.2f} mm "
                   f"without it, {1e3 * second.marker_rms:.2f} with it)",
                   times={"unregressed": sum(first.times.values()), **second.times})


def _announcer(progress: Callable[[Progress], None] | None) -> Callable[[str | Progress], None]:
    """What the pipeline's steps call with a progress message (a Progress, or its text as Problem and the
    solve steps still word it): `progress` receives it as a Progress record."""
    if progress is None:
        return lambda message: None
    return lambda message: progress(Progress.of(message))


def _fixed_groups(base: Parameters, seeded: Parameters, free) -> Parameters:
    """Seeded values for the free groups; base values for the groups that are held."""
    parts = {}
    for b in Parameters.BLOCKS:
        parts[b] = np.array(getattr(seeded if b in free else base, b), dtype=float)
    return Parameters(**parts)
