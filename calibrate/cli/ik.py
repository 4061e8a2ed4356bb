"""``calibrate ik``: every frame's pose of more trials of a subject already calibrated, the subject held fixed.

A lab calibrates a subject once (its static and a trial) and then needs the joint angles of the subject's other
trials: OpenSim's IK tool with the scaled model.  This fits each frame of each trial to the calibrated subject's
markers (calibrate.solve.ik.inverse_kinematics: frame by frame, warm-started from the previous frame), holding
the coordinates an OpenSim subject locks, those the calibration held (``--report``: its report JSON, whose learnt
noise also weighs the markers), those its IK setups hold (``--ik-setup``, repeatable; their marker tasks' weights
weigh the markers, and each cuts its trial to its time range) and ``--lock``'s.  Writes ``<trial>_motion.csv``
and ``<trial>_ik_report.json`` per trial (the fit per marker, what was left out or read back, the notes:
subject_ik.trial_report; and for an OpenSim subject ``<trial>_motion.mot`` and the marker errors as OpenSim's IK
tool reports them, ``<trial>_ik_marker_errors.sto``; with ``--setup-names`` where the IK setup names them), prints
each trial's marker RMS and the markers it fits worst.  ``--ik-setup`` files alone run as OpenSim's IK tool runs
them: the model_file they name (one for all), each one's marker_file and output names.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import CalibrateError
from .args import lock_arg


def add_ik_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``ik`` to the CLI's subparsers."""
    p = subparsers.add_parser(
        "ik", help="every frame's pose of more trials with a calibrated subject held fixed (inverse kinematics)",
        description="Fit every frame of each TRIAL to SUBJECT, a subject calibrate wrote (subject.urdf or "
                    "subject.osim), held fixed: the joint angles of a subject's other trials, as OpenSim's IK "
                    "tool gives them with the scaled model.  Writes <trial>_motion.csv and "
                    "<trial>_ik_report.json (the fit per marker, what was left out or read back; for an .osim "
                    "subject also .mot and the marker errors, _ik_marker_errors.sto) beside each trial or in --out.  "
                    "'calibrate ik --ik-setup XML' alone runs the setup as OpenSim's IK tool does.  Nothing is "
                    "written on an error.")
    p.add_argument("inputs", type=Path, nargs="*", metavar="TRIAL ... SUBJECT",
                   help="the trials (.c3d, .trc, .tsv or .csv), then the calibrated subject (.urdf or .osim); none "
                        "with --ik-setup: the trial each names and the model they name, the outputs where they name "
                        "them, as OpenSim's IK tool runs them")
    p.add_argument("-o", "--out", type=Path, default=None, metavar="DIR",
                   help="the folder for the motions (default: beside each trial)")
    p.add_argument("--ik-setup", type=Path, default=None, metavar="XML", action="append",
                   help="a lab's OpenSim IK setup: its marker tasks' weights weigh the markers (a marker without a "
                        "task is not fitted), the coordinates its tasks hold are locked, its trial cut to its time "
                        "range (repeat it for each trial's setup)")
    p.add_argument("--report", type=Path, default=None, metavar="JSON",
                   help="the report of the calibration that wrote SUBJECT: hold what it held (its locked and "
                        "auto-locked coordinates) and weigh the markers as it weighed them (its learnt noise; an "
                        "--ik-setup's weights win), as its own motion does")
    p.add_argument("--lock", default=None, metavar="DOF[=DEG],...",
                   help="hold these coordinates at a value (default 0 deg) in every frame")
    p.add_argument("--whole-trials", action="store_true", help="every frame, not the IK setups' time ranges")
    p.add_argument("--keep-damaged", action="store_true",
                   help="fit every marker position, as OpenSim's IK does (by default positions that jump away and "
                        "back — spikes, swapped labels —, jitter, or stay behind while their segment moves — a marker "
                        "fallen off — are left out, as the calibration leaves them out)")
    p.add_argument("--other-subject", action="store_true",
                   help="fit a trial whose markers on each segment are more than 10 %% nearer or further apart than "
                        "the subject's (by default refused: another subject's trial)")
    p.add_argument("--subject", default=None, metavar="NAME",
                   help="of trials holding several subjects' markers (Vicon's NAME:RASI), fit NAME's")
    p.add_argument("--markers", type=Path, default=None, metavar="MAP.toml",
                   help="the marker map the calibration renamed the labels by (model label = list of trial labels): "
                        "the same labels then play the same markers (with --report and no --markers: the renaming "
                        "by map its report lists)")
    p.add_argument("--c3d", action="store_true",
                   help="also write each trial as TRIAL-name_calibrated.c3d: its markers with the subject's joint "
                        "centres, model markers and joint angles as model outputs (as calibrate --c3d)")
    p.add_argument("--mjcf", action="store_true",
                   help="also write each motion as MuJoCo qpos rows, TRIAL-name_motion_qpos.csv, for the subject's "
                        "MuJoCo model (calibrate --mjcf or calibrate export-mjcf; docs/mujoco.md)")
    p.add_argument("--setup-names", action="store_true",
                   help="with an .osim subject and --ik-setup: write each trial's .mot and marker errors (.sto) under "
                        "the names and in the folders its IK setup has OpenSim write them (read against the setup's "
                        "folder), where the lab's later setups look for them")
    p.add_argument("--overwrite", action="store_true", help="replace existing motion files")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress and no summary")
    return p


def _named_report(text: str, subject: Path) -> Path | None:
    """The report a subject URDF's first comment names (calibration.report.provenance: "...; its report:
    NAME.json."), where that file is beside the subject; else None."""
    import re

    found = re.search(r"its report: ([^<>\n]+?\.json)\.  ", text[:2000])
    if found is None:
        return None
    path = subject.parent / Path(found.group(1)).name
    return path if path.is_file() else None


def cmd_ik(args: argparse.Namespace) -> int:
    from ..calibration.records import Countdown, Progress
    from ..calibration.subject_ik import IK_COMPILE_FRAMES, TrialFit, fit_trial, trial_report
    from ..io.labels import load_marker_map, map_labels
    from ..io.motion import write_motion_csv
    from ..io.outputs import check_targets
    from ..io.read import read_trial
    from ..io.text import atomic_write_text
    from ..model.model import load_model
    from ..problem.settings import Settings
    from ..solve.ahead import ahead_split, iter_after, run_ahead
    from .commands import Timed
    from .report import progress_for

    from_setup = not args.inputs  # the IK setup's own model and trial, as OpenSim's IK tool runs it
    if from_setup:
        from ..io.osim_setup import ik_setup_inputs

        if not args.ik_setup:
            raise CalibrateError("give one or more trials and then the calibrated subject (calibrate ik TRIAL ... "
                                 "SUBJECT), or --ik-setup files whose model_file and marker_file name them")
        named = [(setup, *ik_setup_inputs(setup)) for setup in args.ik_setup]
        for setup, subject, trial in named:
            for name, got in (("model_file", subject), ("marker_file", trial)):
                if got is None:
                    raise CalibrateError(f"{setup}: its {name} is Unassigned; name it in the setup, or give the "
                                         "trials and the subject: calibrate ik TRIAL ... SUBJECT --ik-setup XML")
        models = list(dict.fromkeys(subject for _, subject, _ in named))
        if len(models) > 1:
            raise CalibrateError(f"{named[0][0]} and {next(s for s, m, _ in named if m != models[0])}: their "
                                 f"model_file names {models[0].name} and {models[1].name}; run each subject's "
                                 "setups apart")
        args.inputs, args.setup_names = [*dict.fromkeys(trial for _, _, trial in named), models[0]], True
    if len(args.inputs) < 2:
        raise CalibrateError("give one or more trials and then the calibrated subject: calibrate ik TRIAL ... SUBJECT")
    *trial_paths, subject_path = args.inputs
    osim = subject_path.suffix.lower() == ".osim"
    if args.out is not None and not args.out.is_dir():
        raise CalibrateError(f"{args.out}: no such folder; create it first or choose another --out")
    named = None
    if args.setup_names:  # the .mot and marker errors where the lab's IK setups have OpenSim write them
        from ..io.osim_setup import setup_outputs

        if not osim:
            raise CalibrateError(f"{subject_path}: --setup-names names the OpenSim outputs (.mot, .sto) of an .osim "
                                 "subject; give the subject .osim")
        if not args.ik_setup:
            raise CalibrateError("--setup-names takes the names the lab's IK setups give; add --ik-setup")
        named = setup_outputs(None, args.ik_setup)
    outputs, opensim_files, folders, locations = [], {}, {}, {}
    written: dict[Path, list[Path]] = {}  # each trial's outputs
    for t in trial_paths:
        folder = args.out if args.out is not None else t.parent
        files = (folder / f"{t.stem}_motion.mot", folder / f"{t.stem}_ik_marker_errors.sto")
        opensim_files[t] = files if named is None else named.outputs_of(t, *files)
        # the model's marker locations where the IK setup asks OpenSim for them (report_marker_locations)
        locations[t] = None if named is None or not osim else named.locations_of(t)
        if from_setup and args.out is None:  # the motion CSV (and the rest) beside the .mot the setup names
            folder = opensim_files[t][0].parent
        folders[t] = folder
        written[t] = [folder / f"{t.stem}_motion.csv", folder / f"{t.stem}_ik_report.json"] + \
            (list(opensim_files[t]) if osim else []) + \
            ([locations[t]] if locations[t] is not None else []) + \
            ([folder / f"{t.stem}_calibrated.c3d"] if args.c3d else []) + \
            ([folder / f"{t.stem}_motion_qpos.csv"] if args.mjcf else [])
        outputs += written[t]
    if named is not None and osim:  # those the lab's IK setups name first (an OpenSim run's earlier outputs?)
        from ..io.osim_setup import SETUP_NAMED_HINT

        check_targets([p for t in trial_paths for p in (*opensim_files[t], locations[t]) if p is not None],
                      args.overwrite, exists_hint=SETUP_NAMED_HINT)
    check_targets(outputs, args.overwrite, inputs={subject_path: "that is the subject"},
                  same="two trials with the same name would write the same motion; use --out or rename them",
                  exists_hint="pass --overwrite to replace it or choose another --out")
    t0 = time.perf_counter()
    model = load_model(subject_path)
    # The coordinates an OpenSim subject locks: its .osim's, or those its URDF carries from the OpenSim base (a
    # subject.urdf calibrate wrote from Pose2Sim's model, its mtp joints free, had folded a foot: 48 mm against 15.6).
    from ..io.osim_info import with_locked

    settings = with_locked(model, Settings())
    weights = None
    setup_lines: list[str] = []
    if args.ik_setup:  # what its coordinate tasks hold, and its marker tasks' weights (a marker it has no task for:
        # not fitted, as the setup's IK tracks only its tasks)
        from ..io.osim_setup import ik_setup_notes, ik_setup_weights, with_ik_setup

        settings = with_ik_setup(model, settings, args.ik_setup)
        weights = ik_setup_weights(args.ik_setup)
        setup_lines = ik_setup_notes(args.ik_setup, model)
    locked = dict(settings.lock)
    static_locks: dict[str, float] = {}  # a static-only calibration's auto-locks: held on its own trials alone
    own: set[tuple[str, int]] = set()  # its trials (file name, frames)
    report_map: dict[str, list[str]] = {}  # the calibration's marker map, as its report lists what it renamed
    if args.report is not None:  # what the calibration held, as its motion holds it
        from ..calibration.subject_ik import report_holds

        holds = report_holds(args.report)
        static_locks = {k: v for k, v in holds.static_locks.items() if k not in locked}
        locked.update(holds.locked)
        own, report_map = set(holds.own), {k: list(v) for k, v in holds.marker_map.items()}
        if weights is None:  # (an --ik-setup's weights win)
            weights = holds.weights
    elif not osim and (named_report := _named_report(model.text, subject_path)) is not None:
        # the subject names its calibration's report (its first comment) and the report is beside it: said, not
        # taken (an explicit --report is what holds and weighs), so the user sees why its motions may differ
        setup_lines.append(f"{subject_path.name} names its calibration's report, {named_report.name}, beside it: "
                           f"--report {named_report} holds what the calibration held and weighs the markers as it "
                           "weighed them, as the calibration's own motion was fitted")
    if args.lock is not None:
        chosen = {name: float(np.radians(deg)) for name, deg in lock_arg(args.lock).items()}
        locked.update(chosen)
        static_locks = {k: v for k, v in static_locks.items() if k not in chosen}
    marker_map = load_marker_map(args.markers) if args.markers is not None else report_map or None
    if args.markers is None and report_map:  # the same labels play the same markers as in the calibration
        lines_map = [f"{args.report.name}: labels renamed as its calibration's marker map renamed them: "
                     + ", ".join(f"{' / '.join(v)} -> {k}" for k, v in report_map.items())]
    else:
        lines_map = []
    trials = [read_trial(t) for t in trial_paths]
    if args.subject is not None:  # one subject of a session's files (Vicon's Derrick:RASI, Viktor:RASI)
        trials = [t.of_subject(args.subject) for t in trials]
    from ..io.c3d import C3D_MAX_FRAMES, write_c3d

    long = [p for p, t in zip(trial_paths, trials, strict=True) if t.n_frames > C3D_MAX_FRAMES]
    if args.c3d and long:
        raise CalibrateError(f"{long[0]}: more frames than a C3D file holds ({C3D_MAX_FRAMES}); leave out --c3d")
    lines: list[str] = []
    if args.ik_setup and not args.whole_trials:
        from ..io.osim_setup import cut_to_setups

        trials, lines = cut_to_setups(trials, None, args.ik_setup)
    lines = setup_lines + lines_map + lines
    params = model.parameters()
    frames = sum(t.n_frames for t in trials)  # long trials together pay for a compile (IK_COMPILE_FRAMES)
    results = []
    released: list[str] = []  # trials fitted without the static-only calibration's auto-locks, and with them
    kept_on: list[str] = []
    jobs = []  # (path, the trial in the subject's labels, what it holds, the markers it fits)
    for path, trial in zip(trial_paths, trials, strict=True):
        held = {**locked, **static_locks} if (path.name, trial.n_frames) in own else locked
        if static_locks:
            (released if held is locked else kept_on).append(path.name)
        trial, _ = map_labels(trial, model.marker_names, marker_map, aliases=True)
        shared = [m for m in model.marker_names if m in trial.labels and (weights is None or weights.get(m, 0) > 0)]
        if len(shared) < 3:
            tasks = " with a marker task of the IK setup" if weights is not None else ""
            raise CalibrateError(f"{path}: only {len(shared)} of its labels are markers of {subject_path.name}{tasks}; "
                                 "give the subject calibrated from this lab's marker set"
                                 + (" and its IK setup" if weights is not None else ""))
        jobs.append((path, trial, held, shared))

    def fitted(k: int, progress=None) -> tuple[TrialFit, float]:
        """Job k's fit and its seconds."""
        path, trial, held, _ = jobs[k]
        start = time.perf_counter()
        got = fit_trial(model, trial, params, held, weights, keep_damaged=args.keep_damaged, source=str(path),
                        check_size=not args.other_subject, compile=frames >= IK_COMPILE_FRAMES, progress=progress)
        return got, time.perf_counter() - start

    # The later trials fitted in a forked child on the other core meanwhile (calibrate.solve.ahead: the same bits;
    # Expert1's 24 trials 20.9 -> 14.9 s): the trials split where their frames are about halved, the child's all fitted
    # before the first is sent (a fit waiting on the pipe would hold the next one back).
    split = ahead_split([t.n_frames for _, t, _, _ in jobs])
    behind = run_ahead(iter_after(lambda: [fitted(k) for k in range(split, len(jobs))])) \
        if split < len(jobs) else None
    try:
        for k, (path, trial, held, shared) in enumerate(jobs):
            if k < split:
                with progress_for(args.quiet, 1, Timed) as say:
                    what = f"fitting the {trial.n_frames} frames of {path.name}"
                    got, seconds = fitted(k, Countdown(say, "ik", what))
            else:
                if k == split:
                    with progress_for(args.quiet, 1, Timed) as say:
                        rest = ", ".join(p.name for p, *_ in jobs[split:])
                        say(Progress("ik", f"{rest}: fitted on the other core meanwhile", long=True))
                got, seconds = next(behind)
            own_lines = [f"{path.name}: {x.text()}" for x in (*got.exchanged_back, *got.jittery)]
            own_lines += [x.text(path.name, subject_path.name) + "; check the labelling" for x in got.relabelled]
            own_lines += got.limit_lines(path.name, subject_path.name)
            if got.unplaced_held:
                own_lines.append(f"{path.name}: {len(got.unplaced)} segments its markers do not place "
                                 f"({', '.join(got.unplaced)}); {', '.join(got.unplaced_held)} held at 0")
            lines += own_lines
            report = trial_report(model, trial, got, {**held, **got.unplaced_held}, shared, str(subject_path),
                                  seconds, [*setup_lines, *lines_map, *own_lines], weights)
            report["outputs"] = [str(o) for o in written[path]]
            results.append((path, trial, got.fit, seconds, got.left_out, shared, report))
    finally:
        if behind is not None:
            behind.close()
    if released:
        lines.append(f"{', '.join(sorted(static_locks))}: the calibration held them because its static, its only "
                     "trial, moved them no more than its markers fix them; fitted in "
                     f"{', '.join(released)}, which it did not fit (--lock holds them)")
        for path, *_, report in results:
            if path.name in released:
                report["notes"].append(lines[-1])
    for (path, trial, fit, _, _, shared, report), folder in zip(results, [folders[t] for t in trial_paths],
                                                                strict=True):
        write_motion_csv(folder / f"{path.stem}_motion.csv", fit.motion)
        atomic_write_text(folder / f"{path.stem}_ik_report.json", json.dumps(report, indent=1, allow_nan=False) + "\n")
        if osim:
            from ..io.osim_export import (
                ik_marker_errors,
                ik_model_marker_locations,
                marker_errors_text,
                marker_locations_text,
                write_mot,
            )

            mot, sto = opensim_files[path]
            write_mot(mot, model, fit.motion)
            # the marker errors as OpenSim's IK tool reports them: the markers it fitted (the IK setup's tasks)
            atomic_write_text(sto, marker_errors_text(fit.motion.times,
                                                      ik_marker_errors(model, params, trial, fit.motion, shared)))
            if locations[path] is not None:
                atomic_write_text(locations[path], marker_locations_text(
                    fit.motion.times, *ik_model_marker_locations(model, params, trial, fit.motion, shared)))
        if args.c3d:
            from ..calibration.c3d_result import with_model_outputs

            write_c3d(folder / f"{path.stem}_calibrated.c3d", with_model_outputs(model, params, trial, fit.motion))
        if args.mjcf:
            from ..io.mjcf import qpos_csv_text

            atomic_write_text(folder / f"{path.stem}_motion_qpos.csv", qpos_csv_text(model, fit.motion))
    if not args.quiet:
        for line in lines:
            print("note: " + line, file=sys.stderr)
        print(f"calibrate ik: {subject_path} held fixed ({len(model.dof_names)} joint coordinates, "
              f"{len(locked)} locked: {', '.join(sorted(locked)) or 'none'}"
              + (f"; on {', '.join(kept_on)} also {', '.join(sorted(static_locks))}" if kept_on else "") + ")")
        for path, trial, fit, seconds, left, _, _ in results:
            err = np.linalg.norm(fit.residuals, axis=2)
            seen = np.flatnonzero(np.isfinite(err).any(axis=0))  # the subject's markers this trial shows
            per_marker = np.sqrt(np.nanmean(err[:, seen] ** 2, axis=0))
            worst = [(model.marker_names[seen[k]], per_marker[k]) for k in np.argsort(-per_marker)[:3]]
            print(f"  {path.name}: {trial.n_frames} frames ({trial.times[0]:.4g} to {trial.times[-1]:.4g} s), "
                  f"marker RMS {1000 * fit.rms:.2f} mm, largest {1000 * np.nanmax(err):.1f} mm; worst markers "
                  + ", ".join(f"{n} {1000 * v:.1f}" for n, v in worst) + " mm"
                  + (f"; {left} marker positions left out (jumps, jitter, a marker left behind)" if left else "")
                  + f"; {seconds:.2f} s")
        print(f"  time {time.perf_counter() - t0:.2f} s; wrote " + ", ".join(str(o) for o in outputs))
    return 0
