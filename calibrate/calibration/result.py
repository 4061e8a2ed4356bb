"""What a calibration returns: the Calibration (frozen when made) and its records — the seed, each
parameter's change, placed markers, rejected outliers."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from calibrate.seed.seeding import Seed

from ..io.measurements import SubjectMeasurements
from ..io.motion import Motion
from ..io.trial import Trial
from ..model.model import Model, Parameters
from ..problem.priors import symmetry_pairs
from ..problem.settings import Settings
from ..seed.geometry import marker_max, marker_rms, per_marker
from ..solve.lm import SolverSummary
from .records import CoordinateNote, JointCentreMarker, ParameterChange
from .report import calibration_report, summary_text, write_outputs


@dataclass(frozen=True)
class NewMarker:
    """A trial marker the base model does not know, and where calibration put it."""

    label: str
    segment: str | None  # None: it rides on no segment (left out)
    position: np.ndarray | None  # (3,) m in the segment frame at the start (subject scale); None if left out
    reason: str  # why this segment (or why none)
    # left out past a joint no known marker moves (hosts.past_joints): the base model's markers it sits by, nearest
    # first (two when they tie: a wrist's), which the trials do not show under their own names (what a marker map
    # might call it)
    sits_by: tuple[str, ...] = ()
    # the hinge whose medial marker its name says (hosts.medial_host), where it rides on the segment that hinge hangs
    # from: its place there starts across the hinge's axis from the lateral marker where the poses put it elsewhere
    # (pipeline._place_new_markers)
    hinge: str = ""
    # placed on the segment the marker map's [segments] names, where the base model's poses put it on another: why to
    # check it (pipeline._declared_doubts; the summary's `check label` line)
    check: str = ""
    declared: bool = False  # placed where the marker map's [segments] puts it (no test of the hosts')
    # the segment it rides on past a joint no model marker poses, where hosts.beyond_joints moved it ("" otherwise)
    past: str = ""


@dataclass(frozen=True)
class Outlier:
    """One marker position left out of the fit: too far from where the fitted model puts it."""

    trial: int  # index into Calibration.trials
    frame: int  # frame of that trial (0-based)
    marker: str
    error: float  # m, when it was rejected
    before: bool = False  # left out before the start by the seeding's tests (a jump, jitter, a marker fallen off),
    # its error at the final fit; otherwise rejected by the solve's outlier test (or by the first run's, which the
    # calibration was run again without: pipeline.refit_outliers)


# A segment whose calibrated scale is this many times the subject's median segment scale, or smaller by as
# much, is flagged (Calibration.implausible): labels the model cannot fit drive a scale that far (a heel and a
# toe label exchanged: tibia 0.0, talus 2.1).  Measured within it (2026-11-26): pig_walk 0.81–1.32, the
# realistic simulator's 1.5 and 2.0 m subjects 0.87–1.22, gait2392 0.82–1.09, Rajagopal 0.61 (ulna_r, its
# forearm barely seen)–1.14.
IMPLAUSIBLE_SCALE = 1.8
# ... and a left segment whose scale is this many times its right partner's, or smaller by as much: a subject's
# bones are symmetric to a few per cent (the symmetry prior's SD is 5 %), so a data-forced 25 % is labels the model
# cannot fit on one side.  Measured (2026-11-27): pig_walk 1.02 at most, gait2392 1.03, Rajagopal 1.09 (radius),
# squats with 3 mm soft-tissue artefact 1.07; labels exchanged for the whole trial on those squats 1.17 (heel and
# toe), 1.44 (elbow and wrist), 1.52 (thigh and shank wands), 1.62 (shoulder and elbow), 1.64 (the tali, with the
# heel and toe exchanged on another solver path, where no segment was beyond IMPLAUSIBLE_SCALE).
IMPLAUSIBLE_ASYMMETRY = 1.25


@dataclass(frozen=True)
class Implausible:
    """A segment calibrated to an implausible size, and the labels to check."""

    segment: str
    scale: float  # its scale against the base model's
    relative: float  # that scale over the subject's median segment scale
    labels: tuple[str, ...]  # its markers and its neighbouring segments' (the trial labels to check for a swap)
    partner: str = ""  # flagged against its left/right partner (IMPLAUSIBLE_ASYMMETRY): the partner's name ...
    partner_scale: float = math.nan  # ... and scale
    # A segment without markers (Pose2Sim's sacrum, welded to the pelvis; a talus): its scale only places the joint
    # centres on it, so the trials' pull on those centres sets it.  (joint, centre's change from the base model, mm)
    centres: tuple[tuple[str, float], ...] = ()

    def cause(self) -> str:
        """What drove a segment without markers to its size (empty for a segment with markers)."""
        if not self.centres:
            return ""
        moved = ", ".join(f"{j} {mm:.0f} mm" for j, mm in self.centres)
        return (f"{self.segment} carries no marker: its scale only places the joint centres on it ({moved} from the "
                f"base model's), where the trials pull them")

    def text(self) -> str:
        """'talus_r scale 0.63', with the partner when flagged against it."""
        out = f"{self.segment} scale {self.scale:.2f}"
        if self.partner:
            ratio = max(self.scale, self.partner_scale) / min(self.scale, self.partner_scale)
            out += f" ({self.partner} {self.partner_scale:.2f}: {100 * (ratio - 1):.0f} % apart)"
        return out

    def to_json(self) -> dict:
        out = {"segment": self.segment, "scale": self.scale, "relative_to_median": self.relative,
               "check_labels": list(self.labels)}
        if self.partner:
            out.update(partner=self.partner, partner_scale=self.partner_scale)
        if self.centres:
            out.update(no_markers=True, centres_mm={j: mm for j, mm in self.centres}, note=self.cause())
        return out


# A trial whose joint angles barely move (the median over the coordinates of their SD over its frames under
# STILL_TRIAL_DEG) is a static trial; in it a standing subject holds each left hinge within a few degrees of its
# right partner.  A hinge pair further apart than STATIC_ASYMMETRY_DEG there is flagged
# (Calibration.static_asymmetry): one side's segment frames sit turned where its markers leave them to the
# priors, and every angle of that joint carries the difference as an offset.  Measured (2026-11-27):
# pig_walk's static trial ankle 26.1 deg (ankle_l -27.0, ankle_r -0.9; Plug-in Gait's own static offsets
# 14.5 and 13.7 deg: the subject's feet are alike), elbow 15.5 (Plug-in Gait's elbows 88.5 and 95.1 deg:
# 6.6 apart), radioulnar 4.3, knee 2.6, subtalar 0.4.
STILL_TRIAL_DEG = 2.0
STATIC_ASYMMETRY_DEG = 20.0
HELD_SD = 1e-6  # rad: a coordinate whose SD over a trial's frames is under this is held (locked), not still


@dataclass(frozen=True)
class StaticHinge:
    """A left/right hinge pair's angles in a static trial: medians over its frames (rad), signed alike
    (their axes mirrored through the sagittal plane)."""

    trial: int
    joint: str  # the anatomical joint without its side ('ankle')
    left: str  # coordinate names
    right: str
    left_angle: float
    right_angle: float

    @property
    def difference(self) -> float:
        return abs(self.left_angle - self.right_angle)

    @property
    def flagged(self) -> bool:
        """Further apart than STATIC_ASYMMETRY_DEG."""
        return self.difference > math.radians(STATIC_ASYMMETRY_DEG)

    def text(self) -> str:
        return (f"{self.left} {math.degrees(self.left_angle):.1f} deg against {self.right} "
                f"{math.degrees(self.right_angle):.1f} ({math.degrees(self.difference):.1f} apart)")

    def to_json(self) -> dict:
        return {"left": self.left, "right": self.right, "left_deg": round(math.degrees(self.left_angle), 3),
                "right_deg": round(math.degrees(self.right_angle), 3),
                "difference_deg": round(math.degrees(self.difference), 3)}


def static_trials(model: Model, motions: Sequence[Motion], neutral: int | None = None) -> list[int]:
    """The static trials among `motions`: the neutral one if given, else those whose joint angles barely
    move (STILL_TRIAL_DEG), the median taken over the coordinates that move at all: a coordinate held at one value
    (locked: a lower-body marker set's trunk and arms, 20 of human.urdf's 32) is no sign of stillness (c3d.org's
    Plug-in Gait walk sample09 was called static, its knees 37 deg apart flagged)."""
    if neutral is not None:
        return [neutral]
    out = []
    for i, m in enumerate(motions):
        if not (m.n_frames and model.n_dofs):
            continue
        sd = np.std(m.angles, axis=0)
        free = sd[sd > HELD_SD]
        if not free.size or math.degrees(float(np.median(free))) < STILL_TRIAL_DEG:
            out.append(i)
    return out


def static_hinges(model: Model, motions: Sequence[Motion], neutral: int | None = None) -> list[StaticHinge]:
    """Every left/right hinge pair (joints named X_l / X_r with one coordinate each whose axes mirror each
    other, as in models/human.urdf and OpenSim's gait models) in every static trial (static_trials)."""
    _, joints, mirror = symmetry_pairs(model, model.parameters().centre)
    out = []
    for t in static_trials(model, motions, neutral):
        med = np.median(motions[t].angles, axis=0)
        for a, b in joints:
            ja, jb = model.joints[a], model.joints[b]
            if len(ja.dofs) != 1 or len(jb.dofs) != 1:
                continue
            da, db = model.dof_index(ja.dofs[0]), model.dof_index(jb.dofs[0])
            c = float(model.dofs[da].axis @ (-mirror * model.dofs[db].axis))  # an axis mirrors as a pseudovector
            if abs(c) < 0.9:  # axes not mirrored: their angles do not compare
                continue
            out.append(StaticHinge(t, ja.name[:-2], ja.dofs[0], jb.dofs[0], float(med[da]),
                                   float(math.copysign(1.0, c) * med[db])))
    return out


@dataclass(frozen=True)
class Calibration:
    """Everything `calibrate` found.  Units: metres, radians, seconds.

    Several trials share `params`; each has its own motion (`motions`, in trial order), and
    `residuals` stacks their frames in that order (`trial_frames(i)` is trial i's slice).
    """

    model: Model  # the subject model's structure: the base model plus any new markers
    trials: tuple[Trial, ...]
    settings: Settings
    params: Parameters  # the subject's geometric parameters
    motions: tuple[Motion, ...]  # coordinates of every frame, per trial
    residuals: np.ndarray  # (F, n_model_markers, 3) model − trial markers (m); NaN where not seen
    initial_residuals: np.ndarray  # the same at the start: seeded geometry, key-frame inverse kinematics
    summary: SolverSummary
    seed: Seed
    changes: list[ParameterChange]
    times: dict[str, float] = field(default_factory=dict)  # stage -> seconds
    ignored_labels: tuple[str, ...] = ()  # trial labels left out (unknown to the model and on no segment)
    unused_markers: tuple[str, ...] = ()  # model markers the trials never show
    compiled: bool = False
    base_model: Model | None = None  # the model calibrated (without the new markers)
    new_markers: tuple[NewMarker, ...] = ()  # trial markers the base model did not know
    outliers: tuple[Outlier, ...] = ()  # marker positions rejected from the fit
    label_maps: tuple = ()  # per trial: calibrate.io.labels.LabelMapping (trial label -> model label), if mapped
    mass: float | None = None  # subject's body mass (kg): segment masses scaled to it on writing; None: kept
    mass_from: str | None = None  # where `mass` came from: "given", or the trial measurements' source
    measurements: SubjectMeasurements | None = None  # the trials' subject measurements (calibrate.io.measurements)
    coordinate_notes: tuple[CoordinateNote, ...] = ()  # what the user should look at (e.g. coordinates driven
    # beyond their limits); `notes` is their text
    held_axes: tuple[str, ...] = ()  # DoFs whose axis calibrate held at the base model's (Settings.auto_hold)
    # (DoF, its turn over the moving trials, rad) for those of held_axes held because the trials turn them too little
    # to place their axis against the skin's turn of the segments (pipeline.NARROW_TURN), not because they are still
    narrow_axes: tuple[tuple[str, float], ...] = ()
    # (joint, its turn over the moving trials, rad: its widest, or where one turn is wide its second) of the centres
    # calibrate held (Settings.hold_centres as used) because the fit carried them far from the base model's where the
    # trials turn the joint too little, or about one axis only, to place a centre against the skin's turn of the
    # segments (pipeline._narrow_centres)
    narrow_centres: tuple[tuple[str, float], ...] = ()
    # (DoF, marker, marker) per hinge whose axis Priors.pair_axis drew along the line of two markers straddling its
    # centre (the epicondyles, the malleoli; calibrate.problem.priors.straddling_pairs), its centre slid to their
    # midpoint
    axis_pairs: tuple[tuple[str, str, str], ...] = ()
    # (joint, marker, marker) per hinge whose axis was held (a still trial's, --hold-axes) or locked and whose centre
    # Priors.on_axis drew to the midpoint of two markers straddling it (calibrate.problem.priors.held_pair_terms)
    pair_centres: tuple[tuple[str, str, str], ...] = ()
    # (joint, its landmark markers, the base model's offset across the axis (m, scale 1)) per turning knee or ankle
    # whose centre Priors.knee_landmark or ankle_landmark held on the axis line through its epicondyles or malleoli
    # (calibrate.problem.priors.landmark_terms)
    landmarks: tuple[tuple[str, tuple[str, ...], tuple[float, float, float]], ...] = ()
    # The knees, ankles and elbows slid along their axes to the population's width where no one measured theirs: the
    # lateral marker's distance from the centre the base model's at the segment's scale
    # (Priors.population_width; pipeline.population_widths)
    population_widths: tuple[str, ...] = ()
    auto_locked: tuple = ()  # records.TradingLock per hinge calibrate locked: its turn and a neighbour's not separated
    neutral: int | None = None  # the trial whose mean joint angles the segment frames were turned to zero
    # (joint, its mean angle there, rad) per hinge whose zero there would carry the trials past its limits: not turned
    not_neutral: tuple[tuple[str, float], ...] = ()
    # (coordinate, rad) the neutral trial was turned to hold on average (calibrate's `pose`: a lab's static pose);
    # None where every angle was turned to zero or no trial is neutral
    pose: tuple[tuple[str, float], ...] | None = None
    # coordinates of `pose` not met: locked at another value, a frame markers fix, a turn past the joint's range ('name
    # (N deg)' where the angle ended more than POSE_MISS from the value)
    pose_unset: tuple[str, ...] = ()
    unresolved: tuple = ()  # calibrate.model.resolve.UnresolvedSegment per segment the markers cannot place (locked)
    # (trial index, UnresolvedSegments) of each trial whose own markers do not place segments the others place: its
    # frames' coordinates there rest on the priors and the neighbouring frames, not on its markers
    unplaced_in_trial: tuple = ()
    unplaced_held: tuple[int, ...] = ()  # those trials whose motion holds those coordinates (as calibrate ik does)
    # per trial, the frames (indices in the trial) whose markers do not place the root (resolve.unplaced_frames): their
    # poses in the motion are bridged from the placed frames either side, held at the trial's edges
    unplaced_frames: tuple[tuple[int, ...], ...] = ()
    noise: dict[str, float] = field(default_factory=dict)  # marker -> noise SD used (m): learnt or the user's
    noise_learnt: bool = False  # whether `noise` was learnt from the residuals (Settings.learn_noise)
    noise_weight: dict[str, float] = field(default_factory=dict)  # marker -> SD its residuals were weighted by
    # (m): the noise SD times the square root of its residuals' correlation time in frames (learnt noise only)
    # (trial index, calibrate.seed.association.Misplaced) per label whose marker rides with another segment than
    # the model's in that trial: labels to check (a label exchanged for the whole trial), reported, not changed
    misplaced: tuple = ()
    # (trial index, calibrate.seed.jitter.Jittery) per marker that jitters (white noise from frame to frame) in
    # stretches of that trial: its positions there left out of the fit
    jittery: tuple = ()
    # (trial index, calibrate.seed.seeding.ExchangedBack) per pair of labels exchanged once in that trial and not back,
    # exchanged back on the frames the base model's distances put the wrong way round
    exchanged_back: tuple = ()
    # (i, j, misfit, pairs) per two trials whose markers on each segment keep distances over 10 % apart (pipeline.
    # trials_apart: the median over `pairs` same-segment pairs of |ratio - 1|): two subjects' trials?
    trials_apart: tuple = ()
    # two moving trials that put markers far apart on their segments (calibrate.calibration.moved.places_apart:
    # PlacesApart): one place per marker cannot fit both
    places_apart: tuple = ()
    # calibrate.seed.association.Exchanged per pair of one segment's labels exchanged between two trials (a walk's
    # heel and toe; their positions left out of the trial the base model says has them exchanged) or, alike in
    # every trial, against the base model (reported, not changed): labels to check
    exchanged: tuple = ()
    # calibrate.calibration.moved.MovedMarker per marker that a still trial shows elsewhere on its segment than
    # the moving trials do: its positions in that still trial were left out (Settings.moved_markers)
    moved: tuple = ()
    # The same test's finds where Settings.moved_markers is off: named, their positions kept in the fit
    moved_kept: tuple = ()
    # calibrate.calibration.moved.ExchangedCluster per segment whose new markers a still trial names otherwise than
    # the moving trials (a symmetric cluster labelled the other way round): read exchanged back in that trial
    relabelled: tuple = ()
    # Every trial still (a static alone): no joint turned, so the joints stay the base model's, scaled; the median
    # SD of the distances between markers on different segments, m, of the trial that moved most (else None)
    still_only: float | None = None
    # The ball joints whose centres calibrate held because the trials are still and do not turn them (statics alone;
    # Settings.auto_hold, pipeline._still_centres): their offsets from their parent segments' markers kept at the
    # base model's
    still_centres: tuple[str, ...] = ()
    # The joints whose centres calibrate held because their child segment carries only a cluster of new labels (a head
    # band: the labels' places and the centre would trade; hosts.cluster_hosts)
    cluster_centres: tuple[str, ...] = ()
    # calibrate.calibration.far_joints.FarJoint per joint that a still trial holds where the moving trials never go:
    # its markers beyond it left out there (Settings.far_joints)
    far_joints: tuple = ()
    # What each trial counted as, in frames (Settings.still_weight: a still trial as a few); () when every frame
    # counted once.
    trial_weights: tuple[float, ...] = ()
    # Markers at a joint centre (points the lab computed there, e.g. OpenSim's R_HJC) that the trials show: each
    # kept at its base-model offset from the centre within Settings.priors.joint_marker
    joint_markers: tuple[JointCentreMarker, ...] = ()
    # calibrate.calibration.regression.HipMotion per hip: how far the trials turn it, and whether that places its
    # centre (two of its angles through 20 deg; a walk's do not)
    hip_motion: tuple = ()
    # Settings.hip_regression "auto": what the calibration without the regression left ("" where it left no hip
    # implausible, or the regression was not asked for so): "applied: ..." (calibrated again with it) or
    # "not applied: ..." (the regression could not run: calibrate.calibration.regression.regression_hips' reason; or
    # it fitted the markers over regression.HIP_AUTO_COST times worse with the hips inside the pelvis)
    hip_regression_auto: str = ""
    # calibrate.calibration.plugin_gait.KneeAxisCheck per knee of each trial carrying Plug-in Gait's femur and tibia
    # bones: its knee axis against the axis its own tibia turns about, and the calibrated knee's
    knee_axes: tuple = ()
    # Per left/right segment pair (name without _l / _r): the posterior SD of their lengths' difference and the SD
    # the priors alone would leave it (m; calibrate.calibration.identifiability.length_differences)
    length_sd: dict[str, tuple[float, float]] = field(default_factory=dict)
    # Per left/right joint pair: the same of the distance between the left centre and the mirrored right one
    # (m; identifiability.mirror_differences)
    mirror_sd: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def notes(self) -> tuple[str, ...]:
        """The coordinate notes as the user reads them."""
        return tuple(n.text() for n in self.coordinate_notes)

    @property
    def trial(self) -> Trial:
        """The first (or only) trial."""
        return self.trials[0]

    @property
    def motion(self) -> Motion:
        """The first (or only) trial's motion; see `motions` for several trials."""
        return self.motions[0]

    def trial_frames(self, i: int) -> slice:
        """Rows of `residuals` that belong to trial i."""
        return trial_spans(self.trials)[i]

    @property
    def marker_rms(self) -> float:
        """RMS 3-D marker error over every observed marker in every frame (m)."""
        return marker_rms(self.residuals)

    @property
    def locked(self) -> dict[str, float]:
        """Every coordinate held at one value in every frame (rad or m): the settings' (the model's locked ones,
        an IK setup's, --lock's, those of segments the markers cannot place) and the hinges calibrate locked itself
        (``auto_locked``).  What a fit of its own trials again holds (calibrate.solve.ik); see ``locked_elsewhere``."""
        return {**dict(self.settings.lock), **{lk.coordinate: lk.value for lk in self.auto_locked}}

    @property
    def locked_elsewhere(self) -> dict[str, float]:
        """What a fit of other trials with this subject holds: ``locked``, but after a calibration on a static alone
        (``still_only``) the settings' locks only, since its auto-locks say no more than that the static moved those
        joints no more than its markers fix them, as every static does (BTKData's FlatFoot walk fitted after its
        static with both forearms' pronation held: the wrists 55 mm off)."""
        if self.still_only is None:
            return self.locked
        auto = {lk.coordinate for lk in self.auto_locked}  # the settings carry them too
        return {k: v for k, v in self.settings.lock if k not in auto}

    @property
    def marker_max(self) -> float:
        """Largest 3-D marker error (m)."""
        return marker_max(self.residuals)

    @property
    def converged(self) -> bool:
        return self.summary.converged

    @property
    def implausible(self) -> list[Implausible]:
        """Segments calibrated IMPLAUSIBLE_SCALE times larger or smaller than the subject's median segment
        scale (a converged fit that is no body: e.g. a talus at half the median when a heel and a toe label
        are exchanged for the whole trial), or IMPLAUSIBLE_ASYMMETRY times their left/right partner's (the
        side further from the median named), with the labels to check."""
        scale = np.asarray(self.params.scale, dtype=float)
        median = float(np.median(scale))
        if not median > 0:
            return []
        model = self.model
        by_name = {sg.name: sg for sg in model.segments}
        def labels(name: str) -> tuple[str, ...]:
            near = [name] + [j.parent for j in model.joints if j.child == name] \
                + [j.child for j in model.joints if j.parent == name]
            return tuple(dict.fromkeys(m for n in near if n in by_name for m in by_name[n].markers))

        moved = {c.item: c.change for c in self.changes if c.group == "centre"}

        def centres(sg) -> tuple[tuple[str, float], ...]:
            """A segment without markers: the joints on it and their centres' changes (mm)."""
            if sg.markers:
                return ()
            return tuple((j.name, float(moved.get(j.name, math.nan))) for j in model.joints if j.parent == sg.name
                         and j.name in moved)

        out = []
        for sg, s in zip(model.segments, scale, strict=True):
            rel = float(s) / median
            if not 1.0 / IMPLAUSIBLE_SCALE <= rel <= IMPLAUSIBLE_SCALE:
                out.append(Implausible(sg.name, float(s), rel, labels(sg.name), centres=centres(sg)))
        flagged = {b.segment for b in out}
        for il, ir in symmetry_pairs(model, model.parameters().centre)[0]:
            left, right = model.segments[il].name, model.segments[ir].name
            if flagged & {left, right}:
                continue
            sl, sr = float(scale[il]), float(scale[ir])
            if max(sl, sr) <= IMPLAUSIBLE_ASYMMETRY * min(sl, sr):
                continue
            # the side further from the subject's median is the one its labels bent
            name, other = (left, right) if abs(math.log(sl / median)) >= abs(math.log(sr / median)) else (right, left)
            s, s_other = (sl, sr) if name == left else (sr, sl)
            out.append(Implausible(name, s, s / median, labels(name), other, s_other))
        return out

    @property
    def static_asymmetry(self) -> list[StaticHinge]:
        """Left/right hinge pairs more than STATIC_ASYMMETRY_DEG apart in a static trial (static_hinges)."""
        return [h for h in static_hinges(self.model, self.motions, self.neutral) if h.flagged]

    @property
    def unidentified(self) -> list[ParameterChange]:
        return [c for c in self.changes if not c.identified]

    def per_marker(self) -> dict[str, tuple[float, float, int]]:
        """Marker name -> (RMS m, max m, frames seen)."""
        return per_marker(self.residuals, self.model.marker_names)

    def report(self) -> dict:
        """The report as plain JSON-ready data (mm, degrees, seconds at the edges)."""
        return calibration_report(self)

    def text(self) -> str:
        """A human-readable summary (what the CLI prints)."""
        return summary_text(self)

    def write(self, urdf=None, motion=None, report=None, overwrite: bool = False,
              extra_times: dict[str, float] | None = None, osim=None, mot=None, html=None,
              progress: Callable[[float], None] | None = None, c3d=None, mjcf=None, qpos=None,
              errors=None, marker_set=None, error_markers=None, scale_set=None, marker_locations=None) -> dict:
        """Write the subject URDF, motion CSV(s), report JSON, the HTML report, each trial as a C3D with the
        joint centres, model markers and angles (`c3d`, one path per trial), for OpenSim the subject .osim,
        .mot motions, each trial's marker errors as OpenSim's IK tool writes them (`errors`, one .sto per
        trial; `error_markers`: per trial the markers they count, None: every marker fitted), its markers as a
        MarkerSet file (`marker_set`), its segments' scale factors as a ScaleSet file (`scale_set`) and each trial's
        model marker locations as OpenSim's IK tool writes them (`marker_locations`, one .sto or None per trial),
        and for MuJoCo the subject's MJCF and qpos CSVs (`qpos`, one path per trial) (those given), all or none; see
        report.write_outputs (`progress(share done)`)."""
        return write_outputs(self, urdf=urdf, motion=motion, report=report, overwrite=overwrite,
                             extra_times=extra_times, osim=osim, mot=mot, html=html, progress=progress, c3d=c3d,
                             mjcf=mjcf, qpos=qpos, errors=errors, marker_set=marker_set,
                             error_markers=error_markers, scale_set=scale_set, marker_locations=marker_locations)


rms = marker_rms  # the name tests and scripts import


def trial_spans(trials: Sequence[Trial]) -> list[slice]:
    """Each trial's frames in the stacked problem."""
    out, at = [], 0
    for t in trials:
        out.append(slice(at, at + t.n_frames))
        at += t.n_frames
    return out
