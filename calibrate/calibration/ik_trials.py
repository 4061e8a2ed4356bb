"""A calibrated subject's other trials fitted and written: what ``calibrate ik`` and a batch's ``ik_trials`` do.

plan_trials reads the subject (subject.urdf or subject.osim as calibrate wrote it), what its calibration's report says
to hold and weigh (subject_ik.report_holds), a lab's IK setups (their tasks' weights, the coordinates they hold, their
time ranges) and the trials, each in the subject's labels: cheap, so that a caller refuses bad input before any fit.
fit_planned fits every trial (subject_ik.fit_trial; the later ones on the other core where that pays,
solve.ahead) and makes each one's report (subject_ik.trial_report); write_fitted writes one trial's files, each whole.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import CalibrateError
from ..io.trial import Trial
from ..model.model import Model, Parameters
from . import subject_ik
from .records import Countdown, Progress
from .report import runs_text
from .subject_ik import TrialFit, fit_trial, report_holds, trial_report


@dataclass(frozen=True)
class IKJob:
    """One trial to fit: its file, the trial (cut to its IK setup's span, in the subject's labels), the coordinates
    it holds (name -> rad or m) and the markers it fits."""

    path: Path
    trial: Trial
    held: dict[str, float]
    fitted: tuple[str, ...]


@dataclass(frozen=True)
class IKPlan:
    """What plan_trials read: the subject held fixed, its parameters, what every trial holds and how the markers are
    weighed, and each trial's job."""

    subject: Path
    model: Model
    params: Parameters
    locked: dict[str, float]  # held in every trial: the subject's locks, the calibration's, the IK setups', lock's
    static_locks: dict[str, float]  # a static-only calibration's auto-locks, held on its own trials alone
    weights: dict[str, float] | None  # marker -> weight (the IK setups' tasks, else the calibration's learnt noise)
    jobs: tuple[IKJob, ...]
    setup_notes: tuple[str, ...]  # what the IK setups and the report say (in every trial's report)
    map_notes: tuple[str, ...]  # the labels renamed as the calibration's marker map renamed them (ditto)
    cut_notes: tuple[str, ...]  # the trials cut to their IK setups' spans
    released: tuple[str, ...] = ()  # trials fitted without static_locks (not the calibration's own)
    kept_on: tuple[str, ...] = ()  # trials fitted with them (the calibration's own)
    # the learnt SDs (m) the weights come from, where they are the calibration's: a trial whose markers scatter beyond
    # them is fitted with its markers weighed alike (subject_ik.fit_trial's noise_sd)
    noise_sd: dict[str, float] | None = None

    @property
    def osim(self) -> bool:
        """Whether the subject is an OpenSim model (its motions also as .mot, its marker errors as .sto)."""
        return self.subject.suffix.lower() == ".osim"

    @property
    def notes(self) -> list[str]:
        """The lines said before any fit, in the order `calibrate ik` prints them."""
        return [*self.setup_notes, *self.map_notes, *self.cut_notes]

    def release_note(self) -> str | None:
        """The line that says which trials were fitted without a static-only calibration's auto-locks."""
        if not self.released:
            return None
        return (f"{', '.join(sorted(self.static_locks))}: the calibration held them because its static, its only "
                "trial, moved them no more than its markers fix them; fitted in "
                f"{', '.join(self.released)}, which it did not fit (--lock holds them)")


@dataclass(frozen=True)
class FittedTrial:
    """One trial fitted: its job, the fit, the seconds it took, its own notes and its report (trial_report; the
    release note added where it applies)."""

    job: IKJob
    got: TrialFit
    seconds: float
    notes: tuple[str, ...]
    report: dict = field(repr=False)


def named_report(text: str, subject: Path) -> Path | None:
    """The report a subject URDF's first comment names (calibration.report.provenance: "...; its report:
    NAME.json."), where that file is beside the subject; else None."""
    import re

    found = re.search(r"its report: ([^<>\n]+?\.json)\.  ", text[:2000])
    if found is None:
        return None
    path = subject.parent / Path(found.group(1)).name
    return path if path.is_file() else None


def plan_trials(subject: str | os.PathLike[str] | Model, trial_paths: Sequence[str | os.PathLike[str]], *,
                report: str | os.PathLike[str] | None = None, ik_setups: Sequence[str | os.PathLike[str]] = (),
                lock: Mapping[str, float] | None = None, markers: str | os.PathLike[str] | None = None,
                subject_name: str | None = None, whole_trials: bool = False) -> IKPlan:
    """Read what fitting `trial_paths` to the calibrated `subject` (its file, or the model read from it) takes: the
    coordinates to hold — the subject's locked ones (an OpenSim subject's, or those its URDF carries), the
    calibration's (`report`, its report JSON: subject_ik.report_holds), the IK setups' (`ik_setups`: a lab's OpenSim
    IK setups, one per trial; their marker tasks weigh the markers and each cuts its trial to its time range unless
    `whole_trials`) and `lock`'s (name -> rad or m) —, the markers' weights, and each trial in the subject's labels
    (`markers`: a marker map, else the one the report lists; `subject_name`: one subject of a session's files).
    CalibrateError (one line) for a trial that shows fewer than three of the subject's (weighted) markers."""
    from ..io.labels import load_marker_map, map_labels
    from ..io.osim_info import with_locked
    from ..io.read import read_trial
    from ..model.model import load_model
    from ..problem.settings import Settings

    model = subject if isinstance(subject, Model) else load_model(subject)
    path = model.path if isinstance(subject, Model) else Path(subject)
    osim = path.suffix.lower() == ".osim"
    # The coordinates an OpenSim subject locks: its .osim's, or those its URDF carries from the OpenSim base (a
    # subject.urdf calibrate wrote from Pose2Sim's model, its mtp joints free, had folded a foot: 48 mm against 15.6).
    settings = with_locked(model, Settings())
    weights = None
    setup_notes: list[str] = []
    if ik_setups:  # what its coordinate tasks hold, and its marker tasks' weights (a marker it has no task for: not
        # fitted, as the setup's IK tracks only its tasks)
        from ..io.osim_setup import ik_setup_notes, ik_setup_weights, with_ik_setup

        settings = with_ik_setup(model, settings, list(ik_setups))
        weights = ik_setup_weights(list(ik_setups))
        setup_notes = ik_setup_notes(list(ik_setups), model)
    locked = dict(settings.lock)
    static_locks: dict[str, float] = {}
    own: frozenset[tuple[str, int]] = frozenset()  # the static-only calibration's trials (file name, frames)
    report_map: dict[str, list[str]] = {}
    noise_sd = None
    if report is not None:  # what the calibration held, as its motion holds it
        holds = report_holds(report)
        static_locks = {k: v for k, v in holds.static_locks.items() if k not in locked}
        locked.update(holds.locked)
        own, report_map = holds.own, {k: list(v) for k, v in holds.marker_map.items()}
        if weights is None:  # (an IK setup's weights win)
            weights, noise_sd = holds.weights, holds.noise_sd
    elif not osim and (named := named_report(model.text, path)) is not None:
        # the subject names its calibration's report (its first comment) and the report is beside it: said, not
        # taken (an explicit report is what holds and weighs), so the user sees why its motions may differ
        setup_notes.append(f"{path.name} names its calibration's report, {named.name}, beside it: --report {named} "
                           "holds what the calibration held and weighs the markers as it weighed them, as the "
                           "calibration's own motion was fitted")
    if lock:
        locked.update(lock)
        static_locks = {k: v for k, v in static_locks.items() if k not in lock}
    marker_map = load_marker_map(markers) if markers is not None else report_map or None
    map_notes = []
    if markers is None and report_map:  # the same labels play the same markers as in the calibration
        map_notes = [f"{Path(report).name}: labels renamed as its calibration's marker map renamed them: "
                     + ", ".join(f"{' / '.join(v)} -> {k}" for k, v in report_map.items())]
    paths = [Path(p) for p in trial_paths]
    trials = [read_trial(p) for p in paths]
    if subject_name is not None:  # one subject of a session's files (Vicon's Derrick:RASI, Viktor:RASI)
        trials = [t.of_subject(subject_name) for t in trials]
    cut_notes: list[str] = []
    if ik_setups and not whole_trials:
        from ..io.osim_setup import cut_to_setups

        trials, cut_notes = cut_to_setups(trials, None, list(ik_setups))
    jobs, released, kept_on = [], [], []
    for p, trial in zip(paths, trials, strict=True):
        held = {**locked, **static_locks} if (p.name, trial.n_frames) in own else locked
        if static_locks:
            (released if held is locked else kept_on).append(p.name)
        trial, _ = map_labels(trial, model.marker_names, marker_map, aliases=True)
        fitted = tuple(m for m in model.marker_names
                       if m in trial.labels and (weights is None or weights.get(m, 0) > 0))
        if len(fitted) < 3:
            tasks = " with a marker task of the IK setup" if weights is not None and ik_setups else ""
            raise CalibrateError(f"{p}: only {len(fitted)} of its labels are markers of {path.name}{tasks}; give the "
                                 "subject calibrated from this lab's marker set"
                                 + (" and its IK setup" if tasks else ""))
        jobs.append(IKJob(p, trial, held, fitted))
    return IKPlan(path, model, model.parameters(), locked, static_locks, weights, tuple(jobs), tuple(setup_notes),
                  tuple(map_notes), tuple(cut_notes), tuple(released), tuple(kept_on), noise_sd)


def fit_planned(plan: IKPlan, *, keep_damaged: bool = False, check_size: bool = True, ahead: bool = True,
                say: Callable[[Progress], None] | None = None) -> list[FittedTrial]:
    """Fit every trial of `plan` to its subject held fixed (subject_ik.fit_trial: `keep_damaged` fits every position;
    `check_size` refuses another subject's trial), each with its report (subject_ik.trial_report).  `ahead`: the later
    trials fitted in a forked child on the other core once the trials together are long enough
    (solve.ahead.ahead_split: the same bits; Expert1's 24 trials 20.9 -> 14.9 s).  `say`: progress (each trial's
    frames fitted; which trials the other core fits)."""
    from ..solve.ahead import ahead_split, iter_after, run_ahead

    jobs = plan.jobs
    # long trials together pay for a compile (subject_ik.IK_COMPILE_FRAMES, read now: a test lowers it)
    compile = sum(j.trial.n_frames for j in jobs) >= subject_ik.IK_COMPILE_FRAMES

    def fitted(k: int, progress=None) -> tuple[TrialFit, float]:
        job = jobs[k]
        start = time.perf_counter()
        got = fit_trial(plan.model, job.trial, plan.params, job.held, plan.weights, keep_damaged=keep_damaged,
                        source=str(job.path), check_size=check_size, compile=compile,
                        progress=progress, noise_sd=plan.noise_sd)
        return got, time.perf_counter() - start

    # The child's trials all fitted before the first is sent (a fit waiting on the pipe would hold the next back).
    split = ahead_split([j.trial.n_frames for j in jobs]) if ahead else len(jobs)
    behind = run_ahead(iter_after(lambda: [fitted(k) for k in range(split, len(jobs))])) \
        if split < len(jobs) else None
    out = []
    name = plan.subject.name
    try:
        for k, job in enumerate(jobs):
            if k < split:
                what = f"fitting the {job.trial.n_frames} frames of {job.path.name}"
                got, seconds = fitted(k, None if say is None else Countdown(say, "ik", what))
            else:
                if k == split and say is not None:
                    rest = ", ".join(j.path.name for j in jobs[split:])
                    say(Progress("ik", f"{rest}: fitted on the other core meanwhile", long=True))
                got, seconds = next(behind)
            own = [f"{job.path.name}: {x.text()}" for x in (*got.exchanged_back, *got.jittery)]
            own += [x.text(job.path.name, name) + "; check the labelling" for x in got.relabelled]
            own += got.limit_lines(job.path.name, name)
            own += got.noise_lines(job.path.name)
            if got.fit.unplaced_frames:
                fs = got.fit.unplaced_frames
                own.append(f"{job.path.name}: frames {runs_text(fs)} ({len(fs)} of {job.trial.n_frames}, from 0) show "
                           f"too few markers to place {plan.model.root}: their poses are bridged from the frames "
                           "either side that place it (held at the trial's edges), not fitted")
            if got.unplaced_held:
                own.append(f"{job.path.name}: {len(got.unplaced)} segments its markers do not place "
                           f"({', '.join(got.unplaced)}); {', '.join(got.unplaced_held)} held at 0")
            report = trial_report(plan.model, job.trial, got, {**job.held, **got.unplaced_held}, job.fitted,
                                  str(plan.subject), seconds, [*plan.setup_notes, *plan.map_notes, *own], plan.weights)
            out.append(FittedTrial(job, got, seconds, tuple(own), report))
    finally:
        if behind is not None:
            behind.close()
    if (line := plan.release_note()) is not None:
        for f in out:
            if f.job.path.name in plan.released:
                f.report["notes"].append(line)
    return out


@dataclass(frozen=True)
class IKFiles:
    """Where one fitted trial's files go: the motion CSV and the report JSON always; an OpenSim subject's .mot and
    marker errors (.sto), the model's marker locations (where an IK setup asks for them), the trial with the
    subject's outputs as C3D and the MuJoCo qpos rows where given."""

    motion: Path
    report: Path
    mot: Path | None = None
    errors: Path | None = None
    locations: Path | None = None
    c3d: Path | None = None
    qpos: Path | None = None

    def paths(self) -> list[Path]:
        """Every file, the report last (a trial whose report exists is done)."""
        return [p for p in (self.motion, self.mot, self.errors, self.locations, self.c3d, self.qpos, self.report)
                if p is not None]


def write_fitted(plan: IKPlan, one: FittedTrial, files: IKFiles) -> None:
    """Write one fitted trial's files (each written whole, the report last, with `files` listed as its outputs)."""
    from ..io.motion import write_motion_csv
    from ..io.text import atomic_write_text

    fit, trial, fitted = one.got.fit, one.job.trial, list(one.job.fitted)
    write_motion_csv(files.motion, fit.motion)
    if plan.osim and (files.mot is not None or files.errors is not None or files.locations is not None):
        from ..io.osim_export import (
            ik_marker_errors,
            ik_model_marker_locations,
            marker_errors_text,
            marker_locations_text,
            write_mot,
        )

        if files.mot is not None:
            write_mot(files.mot, plan.model, fit.motion)
        if files.errors is not None:  # the marker errors as OpenSim's IK tool reports them: the markers it fitted
            atomic_write_text(files.errors, marker_errors_text(
                fit.motion.times, ik_marker_errors(plan.model, plan.params, trial, fit.motion, fitted)))
        if files.locations is not None:
            atomic_write_text(files.locations, marker_locations_text(
                fit.motion.times, *ik_model_marker_locations(plan.model, plan.params, trial, fit.motion, fitted)))
    if files.c3d is not None:
        from ..io.c3d import write_c3d
        from .c3d_result import with_model_outputs

        write_c3d(files.c3d, with_model_outputs(plan.model, plan.params, trial, fit.motion))
    if files.qpos is not None:
        from ..io.mjcf import qpos_csv_text

        atomic_write_text(files.qpos, qpos_csv_text(plan.model, fit.motion))
    report = {**one.report, "outputs": [str(p) for p in files.paths()]}
    atomic_write_text(files.report, json.dumps(report, indent=1, allow_nan=False) + "\n")


def worst_markers(one: FittedTrial, n: int = 3) -> list[tuple[str, float]]:
    """The `n` markers the trial fits worst (name, RMS in m), from its report's per-marker table."""
    per = one.report["markers"]["per_marker"]
    return [(m, 1e-3 * per[m]["rms_mm"]) for m in sorted(per, key=lambda m: -per[m]["rms_mm"])[:n]]
