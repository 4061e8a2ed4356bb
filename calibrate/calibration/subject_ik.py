"""Every frame's pose of another trial of a subject already calibrated, the subject held fixed (``calibrate ik``).

What the calibration does to a trial before it fits it, and what a frame-by-frame fit still needs: the positions that
jump away and back (spikes, swapped labels), jitter, or stay behind while their segment moves (a marker fallen off)
left out (seed.seeding.jumped_samples' checks), two labels exchanged once and not back exchanged back where the
model's distances put them the wrong way round; the coordinates of segments the trial's markers cannot place held at 0
(model.resolve); then calibrate.solve.ik.inverse_kinematics.  A frame-by-frame fit has no outlier test of its own:
on pig_walk's walk one frame of a ghost 1.8 m off turned the right shoulder 230 deg, a marker fallen to the floor the
left knee 19 deg for the rest of the walk (scripts/damage_values.py --ik).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import CalibrateError
from ..io.motion import Motion
from ..io.trial import Trial
from ..model.kinematics import build_kinematics, locked_balls
from ..model.model import Model, Parameters
from ..model.resolve import resolve_carrying
from ..problem.problem import LIMIT_MARGIN, compiled_kinematics
from ..problem.settings import Settings
from ..seed.jitter import Jittery
from ..seed.seeding import ExchangedBack, episodes, exchanged_back, segment_distances, without_broken
from ..solve.ik import IKResult, inverse_kinematics
from .hosts import HOST_FRAMES, local_places, pick_frames
from .identifiability import limit_records
from .moved import EXCHANGE_OWN, SUSPECT, ExchangedCluster, exchange_of
from .records import LimitNote

OTHER_SUBJECT = 0.10  # a trial whose same-segment marker distances differ from the subject's by more than this
# (the median over the pairs, relative) is another subject's: refused
LEARNT_NOISE_HOLDS = 2.0  # a calibration's learnt noise weighs a trial's markers unless one of them scatters about
# its fit over this many times the SD learnt for it (the markers weighed alike instead): Expert1's subject calibrated
# from static1 + walking1 shows at most 1.9 (1.5 on models/human.urdf) on its 12 other walks, 2.3-8.4 on its jumps,
# sit-to-stands and squats, whose shoulder and arm markers ride the shoulder blade as the walk's did not
# (docs/benchmarks.md "Learnt noise on other motions")
SIZE_PAIRS = 10  # judged on this many same-segment marker pairs or more (each SEGMENT_PAIR_MIN or more apart in the
# subject): a video keypoint set's few pairs do not keep their distances (Pose2Sim's demo static: 18 % over 6 pairs)


def size_misfit(model: Model, trial: Trial) -> tuple[float, int]:
    """How far the trial's markers on each segment are from the subject's: the median over the pairs of one segment's
    markers (seeding.segment_distances: 50 mm or more apart in the subject) of |trial distance / subject distance - 1|,
    the trial's distance its median over about 100 frames; and how many pairs.  A segment's markers keep their
    distances in any pose (skin aside), so the subject's own trials read 0.3-1.4 % (BTKData's Plug-in Gait sessions,
    pig_walk, OpenSim's gait2392 and Rajagopal walks; Pose2Sim's augmented keypoints, 72 pairs, 0.9 % and 6.4 % on its
    static), another subject's 11-30 %."""
    D, ref = segment_distances(model, trial)  # the subject as its file has it
    ok = np.isfinite(D)
    out = D[ok] / ref[ok] - 1.0
    return (float(np.median(np.abs(out))) if out.size else 0.0), int(out.size)


@dataclass(frozen=True)
class TrialFit:
    """One trial fitted to a calibrated subject: the fit, the marker positions left out before it (how many), the
    markers that jitter (left out where they do), the coordinates held because the trial's markers do not place
    their segments (name -> value, rad), those segments, and the labels exchanged back (seeding.lone_exchanges)."""

    fit: IKResult
    left_out: int
    jittery: tuple[Jittery, ...]
    unplaced_held: dict[str, float]
    unplaced: tuple[str, ...]
    exchanged_back: tuple[ExchangedBack, ...] = ()
    size_misfit: float | None = None  # size_misfit's figure (None: too few pairs to judge)
    relabelled: tuple[ExchangedCluster, ...] = ()  # clusters the trial names otherwise than the subject, read back
    # coordinates the fit drove beyond the subject's joint limits (identifiability.limit_records, as the calibration
    # notes them): a joint the markers do not resolve, or one the subject moved past the model's range
    beyond_limits: tuple[LimitNote, ...] = ()
    # the markers that scatter about the fit beyond LEARNT_NOISE_HOLDS times the SD the calibration learnt for them
    # (name -> that ratio, largest first): the markers were then weighed alike (learnt_noise_scatter)
    noise_beyond: dict[str, float] = field(default_factory=dict)

    @property
    def weighed_alike(self) -> bool:
        """Whether the learnt noise did not hold for this trial and its markers were weighed alike."""
        return bool(self.noise_beyond)

    def noise_lines(self, source: str) -> list[str]:
        """noise_beyond as `calibrate ik` notes it."""
        if not self.noise_beyond:
            return []
        worst = list(self.noise_beyond.items())
        named = ", ".join(f"{m} {r:.1f}" for m, r in worst[:4]) + (", ..." if len(worst) > 4 else "")
        return [f"{source}: {len(worst)} markers scatter about its fit beyond {LEARNT_NOISE_HOLDS:g} times the noise "
                f"the calibration learnt for them ({named} times): another motion than the calibration's, whose "
                "learnt weights do not hold for it; its markers weighed alike"]

    def limit_lines(self, source: str, subject: str) -> list[str]:
        """beyond_limits as `calibrate ik` notes them, naming the trial `source` and the `subject`."""
        return [f"{source}: {x.coordinate} beyond {subject}'s joint limits in {100 * x.fraction:.0f} % of its frames "
                f"(by up to {np.degrees(x.worst):.0f} deg; the fit allows {np.degrees(LIMIT_MARGIN):.0f} past them, "
                "as the calibration's does): a joint its markers do not resolve, or moved past the model's range "
                f"(--lock {x.coordinate} holds it)" for x in self.beyond_limits]


@dataclass(frozen=True)
class ReportHolds:
    """What a calibration's report JSON says `calibrate ik` should hold and weigh so that the subject's other trials
    are fitted as its own motion was (report_holds)."""

    locked: dict[str, float]  # coordinate -> rad: held in every trial (its locks; auto-locks but a static's alone)
    static_locks: dict[str, float]  # a static-only calibration's auto-locks: held on its own trials alone
    own: frozenset[tuple[str, int]]  # those trials (file name, frames), where static_locks is not empty
    marker_map: dict[str, tuple[str, ...]]  # model label -> the trial labels its marker map renamed
    weights: dict[str, float] | None  # marker -> weight, 1 / its learnt noise SD² (median 1); None: not learnt
    noise_sd: dict[str, float] | None = None  # marker -> the learnt SD the weight comes from (m); None: not learnt


def report_holds(path: str | os.PathLike[str]) -> ReportHolds:
    """The report JSON at `path` (what `calibrate` wrote as <trial>_report.json) read for `calibrate ik`: the
    coordinates its calibration held (report.report_locks; after a static alone its auto-locks hold on that static
    only: BTKData's FlatFoot walk fitted with its static's pronation locks held had its wrists 55 mm off, 17.35 mm
    against 9.23), the labels its marker map renamed, and the markers' weights from its learnt noise.  A file that
    is not such a report, or one edited so that it does not read: CalibrateError, one line."""
    from .html import read_report
    from .report import report_locks

    report = read_report(Path(path))
    if not isinstance(report, dict) or "settings" not in report:
        raise CalibrateError(f"{path}: not a calibrate report (no 'settings'); give the <trial>_report.json the "
                             "calibration wrote")
    try:  # a report edited by hand or cut short: one line, not a Python error
        elsewhere = report_locks(report, elsewhere=True)
        static_locks = {k: v for k, v in report_locks(report).items() if k not in elsewhere}
        own = frozenset((Path(t["source"]).name, int(t["frames"])) for t in report.get("trials") or []
                        if t.get("source")) if static_locks else frozenset()
        renamed: dict[str, list[str]] = {}
        for t in report.get("trials") or []:
            for m in t.get("labels") or []:
                if m.get("how") == "map" and m["trial_label"] not in renamed.get(m["label"], []):
                    renamed.setdefault(str(m["label"]), []).append(str(m["trial_label"]))
        sd = {k: v for k, v in ((report.get("noise") or {}).get("weight_sd_mm") or {}).items()
              if isinstance(v, (int, float)) and v > 0 and math.isfinite(v)}
        weights = None
        if sd:
            w = {k: 1.0 / v**2 for k, v in sd.items()}
            mid = float(np.median(list(w.values())))
            weights = {k: v / mid for k, v in w.items()}
    except (TypeError, ValueError, KeyError, AttributeError, ArithmeticError) as e:
        raise CalibrateError(f"{path}: not readable as the report calibrate writes ({type(e).__name__}: {e}); give the "
                             "<trial>_report.json the calibration wrote, unedited") from None
    return ReportHolds(elsewhere, static_locks, own, {k: tuple(v) for k, v in renamed.items()}, weights,
                       {k: 1e-3 * float(v) for k, v in sd.items()} if sd else None)


#: `calibrate ik`'s trials together this many frames or more: the subject's per-frame code is compiled for them where
#: its calibration did not leave it in the cache (CasADi's virtual machine otherwise).  pig_walk's subject (human.urdf)
#: fits a frame 0.22 ms sooner compiled (6460 frames: 4.5 -> 3.1 s) for a 1.8 s compile, gait2392's 0.47 ms for 1.1 s;
#: Rajagopal2016's subject compiles in 3.9 s: from about 10 000 frames the compile pays (docs/benchmarks.md).
IK_COMPILE_FRAMES = 10_000


def fit_trial(model: Model, trial: Trial, params: Parameters, held: Mapping[str, float],
              weights: Mapping[str, float] | None = None, keep_damaged: bool = False,
              source: str = "the trial", check_size: bool = True,
              progress: Callable[[float], None] | None = None, compile: bool = False,
              noise_sd: Mapping[str, float] | None = None) -> TrialFit:
    """Fit every frame of `trial` (labels the model's: io.labels.map_labels) to `model` at `params`, holding `held`
    (coordinate -> rad or m), the markers weighed by `weights` (an IK setup's tasks; a marker without one is not
    fitted) or alike, under the calibration's limits (LIMIT_MARGIN).  `keep_damaged`: every position fitted, as
    OpenSim's IK does.  `source` names the trial in errors.  Raises CalibrateError when its markers cannot place the
    model's root, or (`check_size`) when they are another subject's (size_misfit over OTHER_SUBJECT: BTKData's
    FlatFoot subject fitted to another's walk at 82 mm RMS).  TrialFit.size_misfit: size_misfit's figure.
    `progress(share of the frames fitted)` every 100 frames (a long trial takes a minute).  The frames are evaluated by
    the subject's compiled per-frame code where its calibration left it in the cache, or (`compile`, for long trials:
    IK_COMPILE_FRAMES) compiled here; by CasADi's virtual machine otherwise (the same bits either way).  `noise_sd`:
    the SDs `weights` were made from (a calibration's learnt noise, m): where a marker scatters about the fit beyond
    LEARNT_NOISE_HOLDS times its SD, the markers are weighed alike and the trial fitted again
    (TrialFit.noise_beyond)."""
    shared = [m for m in model.marker_names if m in trial.labels and (weights is None or weights.get(m, 0) > 0)]
    misfit, pairs = size_misfit(model, trial)
    if check_size and pairs >= SIZE_PAIRS and misfit > OTHER_SUBJECT:
        raise CalibrateError(f"{source}: its markers on each segment are {100 * misfit:.0f} % nearer or further apart "
                             f"than {model.path.name}'s (the median over {pairs} pairs; the subject's own trials read "
                             "0.3-6 %): another subject's trial?  Calibrate its subject, or give --other-subject to "
                             "fit it anyway")
    left, jittery, back = 0, (), []
    if not keep_damaged:
        back: list[ExchangedBack] = []
        jumps, found = episodes(trial, model=model, back=back)
        trial = exchanged_back(trial, back)
        trial, left = without_broken(model, trial, jumps, broken=False)
        jittery = tuple(x for x in found if x.label in shared)
    seen = [m for m in shared if np.isfinite(trial.markers[:, trial.labels.index(m)]).all(axis=1).any()]
    # (a name the model lacks: inverse_kinematics' one line says so)
    # (an upper-body or one-leg trial: the root rides with the marked part, as calibrating: resolve.carried_root)
    res, _ = resolve_carrying(model, seen, locked=[d for d in held if d in model.dof_names])
    if not res.root_resolved:
        raise CalibrateError(f"{source}: its {len(seen)} markers of {model.path.name} cannot place the {model.root} "
                             f"(unresolved: {', '.join(res.names)}); give the subject calibrated from this lab's "
                             "marker set")
    extra = {d: float(np.clip(0.0, model.dofs[model.dof_index(d)].lower, model.dofs[model.dof_index(d)].upper))
             for d in res.lock}
    held = {**held, **extra}
    kin = build_kinematics(model, euler=locked_balls(model, held))  # a ball with a held angle on its three angles
    kin = compiled_kinematics(kin, compile=compile)
    def fitted(t: Trial, start: Motion | None = None) -> IKResult:
        return inverse_kinematics(kin, t, params, locked=held, weights=weights, default_weight=0.0, margin=LIMIT_MARGIN,
                                  start=start, bridge=True,
                                  progress=None if progress is None else lambda done, total: progress(done / total))

    fit = fitted(trial)
    found = () if keep_damaged else exchanged_in_trial(model, trial, params, fit, kin, held, weights)
    if found:  # read as the subject names them, and fitted again
        read = {a: b for x in found for a, b in zip(x.labels, x.read_as, strict=True)}
        trial = replace(trial, labels=tuple(read.get(lab, lab) for lab in trial.labels))
        fit = fitted(trial, fit.motion)
    beyond_noise = learnt_noise_scatter(model, fit, noise_sd) if noise_sd and weights else {}
    if beyond_noise:  # another motion than the calibration's: its markers weighed alike, fitted again from there
        weights = {m: 1.0 for m, w in weights.items() if w > 0}
        fit = fitted(trial, fit.motion)
    beyond = limit_records(model, fit.motion.angles, Settings(lock=dict(held)))
    return TrialFit(fit, left, jittery, extra, res.names if extra else (), tuple(back),
                    misfit if pairs >= SIZE_PAIRS else None, tuple(found), beyond, beyond_noise)


def learnt_noise_scatter(model: Model, fit: IKResult, noise_sd: Mapping[str, float],
                         holds: float = LEARNT_NOISE_HOLDS) -> dict[str, float]:
    """The markers whose scatter about `fit` — the RMS of their residuals per coordinate over the frames they are
    seen in, 10 or more — exceeds `holds` times the SD `noise_sd` gives them (name -> that ratio, largest first);
    empty where none does."""
    sq = np.sum(np.asarray(fit.residuals) ** 2, axis=2)
    seen = np.isfinite(sq)
    out = {}
    for k, name in enumerate(model.marker_names):
        sd = noise_sd.get(name)
        if sd is None or not sd > 0 or seen[:, k].sum() < 10:
            continue
        ratio = float(np.sqrt(np.mean(sq[seen[:, k], k]) / 3.0) / sd)
        if ratio > holds:
            out[name] = ratio
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def trial_report(model: Model, trial: Trial, got: TrialFit, held: Mapping[str, float], fitted: Sequence[str],
                 subject: str, seconds: float, notes: Sequence[str] = (),
                 weights: Mapping[str, float] | None = None) -> dict:
    """One trial's ``calibrate ik`` fit as plain JSON-ready data (mm, degrees, seconds at the edges): the trial (its
    frames, rate and times), the subject held fixed and the coordinates held (`held`, rad; the segments the trial's
    markers do not place among them), the markers fitted (`fitted`, and each one's weight where an IK setup or the
    calibration's noise weighs them), the fit (marker RMS and largest error overall and per marker, frames seen), what
    was left out or read back before the fit (positions, jittery markers, labels exchanged once and back, clusters
    named otherwise than the subject) and the notes printed.  What a lab's batch of trials is checked by without
    reading stderr."""
    from .. import __version__
    from ..seed.geometry import per_marker
    from ..software import software_versions

    fit = got.fit
    if got.weighed_alike and weights is not None:  # the weights the fit used
        weights = {k: 1.0 for k, w in weights.items() if w > 0}
    err = np.linalg.norm(fit.residuals, axis=2)
    mm = lambda x: round(1e3 * float(x), 6)  # noqa: E731
    per = {n: {"rms_mm": mm(r), "max_mm": mm(w), "frames": f}
           for n, (r, w, f) in per_marker(fit.residuals, model.marker_names).items()}
    shown = np.isfinite(fit.marker_rms)
    return {
        "calibrate_version": __version__,
        "software": software_versions(),
        "subject": subject,
        "trial": {"source": trial.source, "frames": trial.n_frames, "rate_hz": trial.rate,
                  "first_frame": trial.first_frame,
                  "times_s": [round(float(trial.times[0]), 6), round(float(trial.times[-1]), 6)] if trial.n_frames
                  else None},
        "held_deg": {k: round(float(np.degrees(v)), 9) for k, v in held.items()},
        "unplaced_segments": list(got.unplaced),
        "markers_fitted": list(fitted),
        "weights": None if weights is None else {k: float(weights[k]) for k in fitted if k in weights},
        "labels_not_fitted": [lab for lab in trial.labels if lab not in fitted],
        "markers": {"rms_mm": mm(fit.rms) if np.isfinite(err).any() else None,
                    "max_mm": mm(np.nanmax(err)) if np.isfinite(err).any() else None,
                    "frames_fitted": int(shown.sum()),
                    "per_marker": per},
        "iterations": {"total": int(fit.iterations.sum()), "max_per_frame": int(fit.iterations.max(initial=0))},
        "positions_left_out": got.left_out,
        "jittery_markers": [x.to_json() for x in got.jittery],
        "exchanged_back": [x.to_json() for x in got.exchanged_back],
        "relabelled": [{k: v for k, v in x.to_json().items() if k not in ("trial", "reference")}
                       for x in got.relabelled],
        "beyond_limits": [{"coordinate": x.coordinate, "fraction": round(x.fraction, 6),
                           "worst_deg": round(float(np.degrees(x.worst)), 6)} for x in got.beyond_limits],
        "size_misfit": None if got.size_misfit is None else round(got.size_misfit, 6),
        # the markers that scattered beyond the calibration's learnt noise (ratio to it): the markers weighed alike
        "learnt_noise_beyond": {k: round(v, 6) for k, v in got.noise_beyond.items()},
        "seconds": round(seconds, 6),
        "notes": list(notes),
    }


def exchanged_in_trial(model: Model, trial: Trial, params: Parameters, fit: IKResult, kin, held: Mapping[str, float],
                       weights: Mapping[str, float] | None = None) -> list[ExchangedCluster]:
    """The clusters `trial` names otherwise than the subject `model` (a symmetric thigh plate labelled the other way
    round: every distance kept), read on its fit `fit`: on each segment where two or more markers fit worse than
    SUSPECT, about HOST_FRAMES frames are posed again without them (the segment carried by its other markers
    and the joints above and below) and each label's place on the segment matched to the subject's places
    (moved.exchange_of, the places read within EXCHANGE_OWN on average).  Expert1's trials on a subject calibrated
    from static1 + walking1: DJ1, walkingTO1 and walking2 name the left plate mirrored, fitted as labelled at 33-36 mm
    RMS (the plate's markers 110-120 mm)."""
    import pinocchio as pin

    err = np.linalg.norm(fit.residuals, axis=2)
    with np.errstate(all="ignore"):
        typical = np.nanmedian(np.where(np.isfinite(err).any(axis=0), err, 0.0), axis=0)
    picked = None
    out = []
    for segment in dict.fromkeys(m.segment for m in model.markers):
        names = [m.name for k, m in enumerate(model.markers) if m.segment == segment and m.name in trial.labels
                 and np.isfinite(err[:, k]).any() and (weights is None or weights.get(m.name, 0) > 0)]
        suspects = [n for n in names if typical[model.marker_index(n)] >= SUSPECT]
        if len(suspects) < 2:
            continue
        picked = picked or pick_frames([trial], HOST_FRAMES)[0]
        posed = inverse_kinematics(kin, picked.select([lab for lab in picked.labels if lab not in suspects]), params,
                                   locked=held, weights=weights, default_weight=0.0, margin=LIMIT_MARGIN)
        local = local_places(model, [(picked, posed)], names, [segment])
        names = [n for n in names if n in local]
        if len(names) < 2:
            continue
        seg = model.pin.frames[model.pin.getFrameId(segment)].placement
        own = np.array([(seg.inverse() * model.pin.frames[model.pin.getFrameId(n, pin.FrameType.BODY)].placement)
                        .translation for n in names])
        read = np.array([np.median(local[n][:, 0], axis=0) for n in names])
        if (x := exchange_of(0, segment, names, read, own, near=EXCHANGE_OWN)) is not None:
            out.append(replace(x, reference=0))  # read by the subject's names (a moving trial's reading, not a still's)
    return out
