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
                        "--ik-setup's weights win), as its own motion does; a trial whose markers scatter beyond "
                        "twice that noise (another motion than the calibration's) is fitted with them weighed alike, "
                        "and a note says so")
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


def cmd_ik(args: argparse.Namespace) -> int:
    from ..calibration.ik_trials import IKFiles, fit_planned, plan_trials, worst_markers, write_fitted
    from ..io.c3d import C3D_MAX_FRAMES
    from ..io.outputs import check_targets
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
    outputs, opensim_files, locations, files = [], {}, {}, {}
    for t in trial_paths:
        folder = args.out if args.out is not None else t.parent
        beside = (folder / f"{t.stem}_motion.mot", folder / f"{t.stem}_ik_marker_errors.sto")
        opensim_files[t] = beside if named is None else named.outputs_of(t, *beside)
        # the model's marker locations where the IK setup asks OpenSim for them (report_marker_locations)
        locations[t] = None if named is None or not osim else named.locations_of(t)
        if from_setup and args.out is None:  # the motion CSV (and the rest) beside the .mot the setup names
            folder = opensim_files[t][0].parent
        mot, sto = opensim_files[t] if osim else (None, None)
        files[t] = IKFiles(folder / f"{t.stem}_motion.csv", folder / f"{t.stem}_ik_report.json", mot, sto,
                           locations[t], folder / f"{t.stem}_calibrated.c3d" if args.c3d else None,
                           folder / f"{t.stem}_motion_qpos.csv" if args.mjcf else None)
        outputs += files[t].paths()
    if named is not None and osim:  # those the lab's IK setups name first (an OpenSim run's earlier outputs?)
        from ..io.osim_setup import SETUP_NAMED_HINT

        check_targets([p for t in trial_paths for p in (*opensim_files[t], locations[t]) if p is not None],
                      args.overwrite, exists_hint=SETUP_NAMED_HINT)
    check_targets(outputs, args.overwrite, inputs={subject_path: "that is the subject"},
                  same="two trials with the same name would write the same motion; use --out or rename them",
                  exists_hint="pass --overwrite to replace it or choose another --out")
    t0 = time.perf_counter()
    lock = None if args.lock is None else {name: float(np.radians(deg)) for name, deg in lock_arg(args.lock).items()}
    plan = plan_trials(subject_path, trial_paths, report=args.report, ik_setups=args.ik_setup or (), lock=lock,
                       markers=args.markers, subject_name=args.subject, whole_trials=args.whole_trials)
    long = [j.path for j in plan.jobs if j.trial.n_frames > C3D_MAX_FRAMES]
    if args.c3d and long:
        raise CalibrateError(f"{long[0]}: more frames than a C3D file holds ({C3D_MAX_FRAMES}); leave out --c3d")
    with progress_for(args.quiet, 1, Timed) as say:
        done = fit_planned(plan, keep_damaged=args.keep_damaged, check_size=not args.other_subject, say=say)
    for one in done:
        write_fitted(plan, one, files[one.job.path])
    if not args.quiet:
        lines = [*plan.notes, *(line for one in done for line in one.notes)]
        if (release := plan.release_note()) is not None:
            lines.append(release)
        for line in lines:
            print("note: " + line, file=sys.stderr)
        print(f"calibrate ik: {subject_path} held fixed ({len(plan.model.dof_names)} joint coordinates, "
              f"{len(plan.locked)} locked: {', '.join(sorted(plan.locked)) or 'none'}"
              + (f"; on {', '.join(plan.kept_on)} also {', '.join(sorted(plan.static_locks))}" if plan.kept_on
                 else "") + ")")
        for one in done:
            fit, trial = one.got.fit, one.job.trial
            err = np.linalg.norm(fit.residuals, axis=2)
            left = one.got.left_out
            print(f"  {one.job.path.name}: {trial.n_frames} frames ({trial.times[0]:.4g} to {trial.times[-1]:.4g} s), "
                  f"marker RMS {1000 * fit.rms:.2f} mm, largest {1000 * np.nanmax(err):.1f} mm; worst markers "
                  + ", ".join(f"{n} {1000 * v:.1f}" for n, v in worst_markers(one)) + " mm"
                  + (f"; {left} marker positions left out (jumps, jitter, a marker left behind)" if left else "")
                  + ("; markers weighed alike (beyond the learnt noise)" if one.got.weighed_alike else "")
                  + f"; {one.seconds:.2f} s")
        print(f"  time {time.perf_counter() - t0:.2f} s; wrote " + ", ".join(str(o) for o in outputs))
    return 0
