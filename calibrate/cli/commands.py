"""The commands behind the command line (calibrate.cli.main parses, these run): calibrate, simulate,
demo, inspect, import-osim, joints."""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate.cli.args import lock_arg

from ..calibration.records import Countdown, Progress
from ..errors import CalibrateError
from ..io.labels import UNLABELLED
from ..io.outputs import check_targets
from ..seed.geometry import marker_rms
from .report import progress_for

DEFAULT_MODEL = Path(__file__).resolve().parent.parent.parent / "models" / "human.urdf"


def default_model() -> Path:
    """models/human.urdf of the source tree; in an installed package (no source tree) the same
    model is generated from calibrate.model.human into the temporary directory."""
    if DEFAULT_MODEL.exists():
        return DEFAULT_MODEL
    import tempfile

    from ..model.human import build_human_urdf

    path = Path(tempfile.gettempdir()) / "calibrate-human.urdf"
    text = build_human_urdf()
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def progress_printer(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def run_simulation(args: argparse.Namespace):
    from ..model.model import load_model
    from ..simulation.simulate import MOTIONS, simulate_realistic, write_simulation

    if args.marker_set is not None and (args.model is None or args.model.suffix.lower() != ".osim"):
        raise CalibrateError(f"{args.marker_set}: --marker-set adds markers to an OpenSim model; give the .osim with "
                             "--model")
    model = load_model(args.model or default_model(), args.marker_set)
    if args.out.exists() and not args.out.is_dir():
        raise CalibrateError(f"{args.out}: exists and is not a directory; choose another --out")
    if not getattr(args, "overwrite", True):
        from ..io.c3d import C3D_MAX_FRAMES

        trial_name = "trial.trc" if args.frames > C3D_MAX_FRAMES else "trial.c3d"
        extra = ("cameras.toml", "detections.npz", "truth_detections.npz") if getattr(args, "cameras", None) else ()
        for name in (trial_name, "truth.urdf", "truth_motion.csv", "truth_corruptions.csv", *extra):
            if (args.out / name).exists():
                raise CalibrateError(
                    f"{args.out / name}: exists; pass --overwrite to replace it or choose another --out"
                )
    t0 = time.perf_counter()
    opts = {k: v for k, v in (("sta_mm", args.sta_mm), ("height", args.height), ("swaps", args.swaps),
                              ("spikes", args.spikes), ("gap_fraction", args.gap_fraction)) if v is not None}
    try:
        if args.realistic:
            if args.gaps:  # the occlusions of --gaps in place of the gap fraction
                opts.setdefault("gap_fraction", 0.0)
            sim = simulate_realistic(model, args.seed, args.frames, args.rate, args.noise_mm,
                                     motion=args.motion or "overhead", gaps=args.gaps, **opts)
        else:
            simulate = MOTIONS[args.motion or "squats"]
            sim = simulate(model, frames=args.frames, rate=args.rate, noise_mm=args.noise_mm, gaps=args.gaps,
                           seed=args.seed, **opts)
    except ValueError as e:
        raise CalibrateError(f"simulate: {e}") from None
    stale = args.out / "truth_corruptions.csv"
    if not sim.corruptions and stale.exists():
        stale.unlink()  # from an earlier run into this folder (overwriting was allowed above)
    try:
        paths = write_simulation(sim, args.out)
        if getattr(args, "cameras", None):
            from .track import write_simulated_cameras

            paths.update(write_simulated_cameras(sim, args.out, args.cameras, args.seed))
    except OSError as e:
        raise CalibrateError(f"{args.out}: cannot write ({e.strerror}); choose a writable --out") from None
    return model, sim, paths, time.perf_counter() - t0


def cmd_simulate(args: argparse.Namespace) -> int:
    model, sim, paths, dt = run_simulation(args)
    gaps = float(np.isnan(sim.trial.markers[..., 0]).mean())
    print(f"simulated {sim.trial.n_frames} frames at {sim.trial.rate:g} Hz of {len(model.markers)} markers "
          f"(noise {args.noise_mm:g} mm, gaps {100 * gaps:.1f} %) in {dt:.2f} s")
    extras = []
    if sim.stature is not None:
        extras.append(f"stature {sim.stature:.3f} m")
    if sim.sta_amplitude is not None:
        extras.append(f"soft-tissue artefact up to {1000 * np.linalg.norm(sim.artefact, axis=2).max():.1f} mm")
    if sim.corruptions:
        kinds = [c.kind for c in sim.corruptions]
        extras.append(f"{kinds.count('swap')} swapped and {kinds.count('spike')} spiked marker samples")
    if extras:
        print("  " + "; ".join(extras))
    for key in ("trial", "truth", "motion", "corruptions", "cameras", "detections", "truth_detections"):
        if key in paths:
            print(f"  {key:11s} {paths[key]}")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from ..calibration.pipeline import calibrate
    from ..io.config import load_settings, settings_from_dict
    from ..io.labels import load_marker_map
    from ..io.read import read_trial
    from ..model.model import load_model
    from ..problem.settings import Settings

    if not args.inputs:
        _inputs_from_setups(args)
    if len(args.inputs) < 2:
        raise CalibrateError("give one or more trials and then the base model: calibrate TRIAL [TRIAL ...] MODEL")
    *trial_paths, model_path = args.inputs
    if model_path.suffix.lower() in (".c3d", ".trc", ".tsv", ".csv"):
        raise CalibrateError(f"{model_path}: the last argument must be the base model (.urdf or .osim), "
                             "after the trials")
    if args.frames is not None and len(trial_paths) > 1:
        raise CalibrateError("--frames applies to a single trial; cut the trials first or give one trial")
    if args.motion is not None and len(trial_paths) > 1:
        raise CalibrateError("--motion names one file; with several trials each gets TRIAL_motion.csv (beside -o's "
                             "URDF, or beside the trial)")
    from_osim = model_path.suffix.lower() == ".osim"  # then also the subject .osim and .mot motions, OpenSim's names
    output = None if args.output is None else Path(args.output)
    stem = trial_paths[0].with_suffix("")
    if output is not None and (str(args.output).endswith(("/", os.sep)) or output.is_dir()):
        # -o results/ (a folder): the subject under the first trial's name in it, the other outputs beside it
        if not output.is_dir():
            raise CalibrateError(f"{args.output}: no such folder; create it first or choose another -o")
        output = output / (stem.name + ".urdf")
    if output is not None and output.suffix.lower() == ".osim":
        # An OpenSim user names the subject .osim: the URDF goes beside it under the same name.
        if not from_osim:
            raise CalibrateError(f"{output}: a subject .osim is written from an OpenSim base model, and "
                                 f"{model_path.name} is not one; give -o NAME.urdf")
        output = output.with_suffix(".urdf")
    elif output is not None and not output.suffix:  # -o out/subject02: the subject's name, written subject02.urdf
        output = output.with_name(output.name + ".urdf")
    out_urdf = output or stem.with_name(stem.name + ".urdf")
    # The outputs stay together: beside -o's URDF when it is given (a trial's own folder may be a shared,
    # read-only data set), else beside the first trial.
    folder = out_urdf.parent if output else None
    out_motions = [args.motion] if args.motion else [(folder or t.parent) / (t.stem + "_motion.csv")
                                                      for t in trial_paths]
    out_report = args.report or (folder or stem.parent) / (stem.name + "_report.json")
    settings = load_settings(args.config) if args.config else Settings()
    flags: dict = {}
    if args.free is not None:
        flags["free"] = [g.strip() for g in args.free.split(",") if g.strip()]
    if args.loss is not None:
        flags["loss"] = args.loss
    if args.noise_mm is not None:
        flags["noise_mm"] = args.noise_mm
    if args.no_learn_noise:
        flags["learn_noise"] = False
    if args.still_weight is not None:
        flags["still_weight"] = args.still_weight
    if args.no_seed:
        flags["seed"] = False
    if args.no_new_markers:
        flags["new_markers"] = False
    if args.outlier_sigmas is not None:
        flags["outlier_sigmas"] = args.outlier_sigmas
    if args.lock is not None:
        flags["lock_deg"] = lock_arg(args.lock)
    if args.hold_axes is not None:
        flags["hold_axes"] = [d.strip() for d in args.hold_axes.split(",") if d.strip()]
    if args.hold_centres is not None:
        flags["hold_centres"] = [d.strip() for d in args.hold_centres.split(",") if d.strip()]
    if args.no_auto_hold:
        flags["auto_hold"] = False
    if args.moved_markers:
        flags["moved_markers"] = True
    if args.keep_far_joints:
        flags["far_joints"] = False
    if args.hip_regression:
        flags["hip_regression"] = True
    if args.hip_regression_auto:
        flags["hip_regression"] = "auto"
    if args.no_hip_regression:
        flags["hip_regression"] = False
    if args.segment_frames is not None:
        flags["segment_frames"] = args.segment_frames
    if args.memory_mb is not None:
        flags["memory_mb"] = args.memory_mb
    if flags:
        settings = settings_from_dict(flags, "command line", settings)
    out_c3ds = [m.with_name(t.stem + "_calibrated.c3d") for m, t in zip(out_motions, trial_paths, strict=False)] \
        if args.c3d else []
    out_mujoco = [out_urdf.with_name(out_urdf.stem + "_mujoco.xml"),
                  *(m.with_name(m.stem + "_qpos.csv") for m in out_motions)] if args.mjcf else []
    outputs = [out_urdf, *out_motions, out_report, *([args.html] if args.html is not None else []), *out_c3ds,
               *out_mujoco]
    if args.html is not None and args.html.suffix.lower() not in (".html", ".htm"):
        raise CalibrateError(f"{args.html}: the HTML report needs an .html name (--html report.html)")
    out_osim = out_urdf.with_suffix(".osim")
    out_mots = [m.with_suffix(".mot") for m in out_motions]
    # Each trial's marker errors as OpenSim's IK tool reports them (<name>_ik_marker_errors.sto), beside its .mot.
    out_errors = [m.with_name(t.stem + "_ik_marker_errors.sto") for m, t in zip(out_motions, trial_paths, strict=False)]
    out_markers = None  # the subject's markers as a MarkerSet file: where a Scale setup names one (--setup-names)
    out_scales = None  # its segments' scale factors as a ScaleSet file: where a Scale setup names one (--setup-names)
    out_locations: list[Path | None] = []  # model marker locations, where an IK setup asks for them (--setup-names)
    setups = None  # the lab's setups' output names and tracked markers, read once (calibrate.io.osim_setup)
    if args.scale_setup is not None or args.ik_setup:
        from ..io.osim_setup import setup_outputs

        setups = setup_outputs(args.scale_setup, args.ik_setup)
    if args.setup_names:
        out_osim, out_markers, out_mots, out_errors = _setup_names(args, from_osim, setups, trial_paths, out_osim,
                                                                   out_mots, out_errors)
        out_scales = setups.scales
        out_locations = [setups.locations_of(t) for t in trial_paths] if setups.locations else []
    if from_osim:
        outputs += [out_osim, *out_mots, *out_errors,
                    *(p for p in (out_markers, out_scales, *out_locations) if p is not None)]
    # Check the destinations before any work, so a long run never ends in a refusal: those the lab's setups name
    # first (an OpenSim run's earlier outputs, most likely), then every one.
    if args.setup_names and from_osim:
        from ..io.osim_setup import SETUP_NAMED_HINT

        check_targets([p for p in (out_osim, out_markers, out_scales, *out_mots, *out_errors, *out_locations)
                       if p is not None], args.overwrite, exists_hint=SETUP_NAMED_HINT)
    check_targets(outputs, args.overwrite,
                  inputs={model_path: "that is the base model; refusing to overwrite it (choose another -o)"},
                  same="two outputs would be the same file (two trials with the same name?); use -o/--report "
                       "or rename the trials",
                  exists_hint="pass --overwrite to replace it or choose another name")
    progress = progress_for(args.quiet, settings.max_iterations, Timed)
    t0 = time.perf_counter()
    setup = None
    if args.scale_setup is not None:  # the lab's Scale setup: the subject's mass and its marker set
        if not from_osim:
            raise CalibrateError(f"{args.scale_setup}: --scale-setup reads an OpenSim pipeline's Scale setup for an "
                                 f"OpenSim base model (MODEL.osim), and {model_path.name} is not one; give --mass")
        from ..io.osim_setup import scale_setup

        setup = scale_setup(args.scale_setup)
    marker_set = args.marker_set if args.marker_set is not None or setup is None else setup.marker_set
    mass = args.mass if args.mass is not None or setup is None else setup.mass
    model = load_model(model_path, marker_set)
    if setup is not None and not args.quiet:
        taken = ([f"mass {mass:g} kg"] if args.mass is None and mass is not None else []) + (
            [f"marker set {marker_set.name}"] if args.marker_set is None and marker_set is not None else [])
        progress_printer(f"note: {setup.path.name}: " + (", ".join(taken) + " taken" if taken else "nothing taken "
                         "(no mass or marker set there, or given on the command line)")
                         + ("; its preserve_mass_distribution is false, yet calibrate scales every segment's mass "
                            "alike (OpenSim's Scale would first scale each by its size)"
                            if mass is not None and not setup.preserve_mass else ""))
    if model_path.suffix.lower() == ".osim":  # the model's locked coordinates, unless --lock/--config set them
        from ..io.osim_info import import_summary, osim_info, with_locked

        settings = with_locked(model, settings)
        said = import_summary(osim_info(model))  # type: ignore[arg-type]
        if said and not args.quiet:
            progress_printer(f"note: {model_path.name}: {'; '.join(said)}; see 'calibrate inspect {model_path}'")
    if args.ik_setup is not None:  # the coordinates the lab's IK holds, unless --lock/--config set them
        from ..io.osim_setup import ik_setup_notes, with_ik_setup

        settings = with_ik_setup(model, settings, args.ik_setup)
        if not args.quiet:
            for line in ik_setup_notes(args.ik_setup, model):
                progress_printer("note: " + line)
    marker_map = load_marker_map(args.markers) if args.markers else None
    with progress as say:
        trials = [read_trial(t, progress=Countdown(say, "read", f"reading {t.name}")) for t in trial_paths]
        if args.subject is not None:  # one subject of a session's files (Vicon's Derrick:RASI, Viktor:RASI)
            trials = [t.of_subject(args.subject) for t in trials]
        from ..io.c3d import C3D_MAX_FRAMES

        long = [p for p, t in zip(trial_paths, trials, strict=True) if t.n_frames > C3D_MAX_FRAMES]
        if args.c3d and long and args.frames is None:  # refused before the work, not after it
            raise CalibrateError(f"{long[0]}: more frames than a C3D file holds ({C3D_MAX_FRAMES}); leave out --c3d "
                                 "or cut the trial (--frames)")
        from ..model.sides import side_mismatches

        sides = [x for x in side_mismatches(model) if any(x.marker in t.labels for t in trials)]
        if sides:  # the trial's marker of that name would be fitted on the other side (Hamner2010's LHJC / RHJC)
            print(f"warning: {model_path.name}: " + "; ".join(x.text() for x in sides) + " (the model's labels "
                  "exchanged? the trials' markers of those names are fitted where the model puts them; see "
                  f"'calibrate inspect {model_path}')", file=sys.stderr)
        if not args.whole_trials and (setup is not None or args.ik_setup is not None):
            # The frames the lab's Scale and IK tools fit: the static's still span, the walk's cycle.
            from ..io.osim_setup import cut_to_setups

            before = [t.n_frames for t in trials]
            trials, lines = cut_to_setups(trials, setup, args.ik_setup)
            if args.frames is not None and trials[0].n_frames != before[0]:
                raise CalibrateError(f"--frames and the setup's time range both select frames of {trial_paths[0]}; "
                                     "drop --frames, or pass --whole-trials to use --frames alone")
            if not args.quiet:
                for line in lines:
                    progress_printer("note: " + line)
        if args.frames is not None:
            trial = trials[0]
            idx = range(trial.n_frames)[args.frames]
            if len(idx) == 0 or idx.step != 1:
                raise CalibrateError(f"--frames {args.frames.start}:{args.frames.stop}: selects no frames of "
                                     f"{trial_paths[0]} ({trial.n_frames} frames, 0-based)")
            trials[0] = trial.frames(idx.start, idx.stop)
        load_s = time.perf_counter() - t0
        if args.neutral is not None and args.neutral > len(trials):
            raise CalibrateError(f"--neutral {args.neutral}: there are only {len(trials)} trials; give the number of "
                                 f"the static trial (1 = the first)")
        neutral, pose = None if args.neutral is None else args.neutral - 1, None
        if setup is not None:  # the static pose the lab's marker placer holds (its coordinate tasks)
            from ..io.osim_setup import setup_pose

            k, held, lines = setup_pose(setup.path, model, trials, [p.name for p in trial_paths])
            if held is not None and neutral is not None:
                lines = [f"{setup.path.name}: its MarkerPlacer's coordinate tasks not applied: --neutral turns every "
                         "joint to zero instead"]
            elif held is not None:
                neutral, pose = k, held
            if not args.quiet:
                for line in lines:
                    progress_printer("note: " + line)
        cal = calibrate(model, trials, settings, marker_map=marker_map, aliases=not args.no_aliases, mass=mass,
                        neutral=neutral, pose=pose, progress=say)
        if setup is not None and args.mass is None and mass is not None:
            cal = replace(cal, mass_from=str(setup.path))  # the summary, the report and the HTML name the file
        cal = replace(cal, times={"load": load_s, **cal.times})
        opensim = {"osim": out_osim, "mot": out_mots, "errors": out_errors, "marker_set": out_markers,
                   "scale_set": out_scales, "marker_locations": out_locations or None,
                   # the errors count the markers each trial's IK setup tracks, as OpenSim's IK's do
                   "error_markers": [setups.tracked_of(t) for t in trial_paths] if args.ik_setup else None} \
            if from_osim else {}
        cal = write_timed(cal, urdf=out_urdf, motion=out_motions, report=out_report, overwrite=args.overwrite,
                          html=args.html, progress=Countdown(say, "write", "the motion, the subject and the report"),
                          c3d=out_c3ds or None, **opensim,
                          **({"mjcf": out_mujoco[0], "qpos": out_mujoco[1:]} if out_mujoco else {}))
    unlabelled = [lab for lab in cal.ignored_labels if UNLABELLED.fullmatch(lab)]
    named = [lab for lab in cal.ignored_labels if not UNLABELLED.fullmatch(lab)]
    empty = [lab for lab in named if any(lab in t.labels for t in cal.trials)
             and not any(np.isfinite(t.marker(lab)).any() for t in cal.trials if lab in t.labels)]
    named = [lab for lab in named if lab not in empty]
    if empty and not args.quiet:  # a marker set's labels the session did not use (BTKData's FunctionalWalk: arms)
        print(f"note: {len(empty)} trial label{'' if len(empty) == 1 else 's'} with no position in any frame, "
              f"ignored: {', '.join(empty)}", file=sys.stderr)
    if named:
        one = len(named) == 1
        why = ("is not a marker of" if one else "are not markers of") if not settings.new_markers else (
            "rides on no segment of" if one else "ride on no segment of")
        by = {m.label: " or ".join(m.sits_by) for m in cal.new_markers if m.sits_by and m.label in named}
        hint = (f"; {len(by)} of them sit where {model.path.name} has markers the trial does not show "
                f"({', '.join(f'{lab} near {mk}' for lab, mk in by.items())}): if they are those markers, name "
                "them so in a marker map (--markers map.toml)" if by else "")
        if from_osim and marker_set is None and len(named) > len(by):
            # (gait2392's walk on Rajagopal2016.osim: its midfoot, biceps and head labels left out, its trunk fitted
            # in another basin; with gait2392's marker set, none left out)
            hint += ("; an OpenSim marker set that places them on the model's bodies (the lab's MarkerSet file, as "
                     "its Scale setup names it: --marker-set FILE.xml) fits them")
        if settings.new_markers and len(named) > len(by):
            hint += ("; a label you know the segment of goes there by the marker map's [segments] table (femur_l = "
                     "[\"LABEL\"], --markers map.toml)")
        print(f"warning: {len(named)} trial label{'' if one else 's'} {why} {model.path.name} and "
              f"{'is' if one else 'are'} ignored: {', '.join(named)}{hint}", file=sys.stderr)
    if unlabelled:  # Vicon Nexus's '*115': trajectories nobody labelled, not markers the model lacks
        many = "y" if len(unlabelled) == 1 else "ies"
        print(f"warning: {len(unlabelled)} unlabelled trajector{many} ignored ({', '.join(unlabelled[:4])}"
              f"{', ...' if len(unlabelled) > 4 else ''}); label them in the capture software to use them",
              file=sys.stderr)
    print(cal.text())
    print("")
    print("wrote " + "\n      ".join(str(p) for p in outputs))
    if from_osim:
        from ..io.osim_forces import forces_written

        for line in forces_written(out_osim):
            print(f"      {out_osim.name}: {line}")
    if cal.misplaced:
        check = dict.fromkeys(x for _, m in cal.misplaced for x in (m.label, *m.partners))
        pairs = dict.fromkeys(f"{a}/{b}" for _, m in cal.misplaced for a, b in m.exchanges)
        print(f"warning: labels to check (they move with another segment's markers than the model's; exchanged for "
              f"the whole trial?): {', '.join(check)}" + (f"; exchanges that fit: {', '.join(pairs)}" if pairs else "")
              + " (see 'check label' above)", file=sys.stderr)
    if cal.trials_apart:
        print("warning: trials whose markers on each segment keep distances over 10 % apart: two subjects' trials? "
              "(see 'subjects?' above)", file=sys.stderr)
    if cal.exchanged_back:
        pairs = ", ".join(dict.fromkeys("/".join(x.labels) for _, x in cal.exchanged_back))
        print(f"warning: labels exchanged and not back, exchanged back where they ride with each other's segment or "
              f"the base model puts them the wrong way round: {pairs} (see 'exchanged' above); check the labelling",
              file=sys.stderr)
    if cal.relabelled:
        pairs = ", ".join(f"{a} as {b}" for x in cal.relabelled for a, b in zip(x.labels, x.read_as, strict=True))
        print(f"warning: cluster labels a trial names otherwise than the others, read as they name them: {pairs} (see "
              "'relabelled' above); check the labelling", file=sys.stderr)
    if cal.jittery:
        names = ", ".join(dict.fromkeys(x.label for _, x in cal.jittery))
        print(f"warning: markers that jitter, left out where they do: {names} (see 'jitters' above)", file=sys.stderr)
    for x in cal.exchanged:
        pair = [Path(cal.trials[k].source).name if cal.trials[k].source else f"trial {k + 1}" for k in x.trials]
        names = " and ".join(pair)
        where = f"in {names}, against the base model" if x.against_model else f"between {names}"
        print(f"warning: labels to check: {' and '.join(x.labels)} exchanged {where} (see 'check labels' above)",
              file=sys.stderr)
    if not cal.converged:
        print(f"warning: the solver did not converge ({cal.summary.termination}); the best result so far was "
              "written and is flagged in the report", file=sys.stderr)
        return 1
    return 0


def _inputs_from_setups(args) -> None:
    """No trial or model given: those the lab's Scale setup (its generic model and static trial) and IK setups (each
    its trial) name, as OpenSim's tools run them, their outputs where they name them (args.inputs, args.setup_names
    set so); without -o, calibrate's own outputs (URDF, CSVs, report) beside the subject .osim the Scale setup
    names, not among the lab's data."""
    from ..io.osim_setup import ik_setup_inputs, scale_setup_inputs, setup_outputs

    if args.scale_setup is None:
        raise CalibrateError("give the trials and then the base model (calibrate TRIAL [TRIAL ...] MODEL), or the "
                             "lab's --scale-setup (and --ik-setup) naming them")
    model, static = scale_setup_inputs(args.scale_setup)
    named = [(args.scale_setup, "GenericModelMaker's model_file", model),
             (args.scale_setup, "marker placer's marker_file", static),
             *((ik, "marker_file", ik_setup_inputs(ik)[1]) for ik in args.ik_setup or ())]
    for setup, what, path in named:
        if path is None:
            raise CalibrateError(f"{setup}: its {what} is Unassigned; name it in the setup, or give the trials and "
                                 "the model: calibrate TRIAL [TRIAL ...] MODEL --scale-setup XML")
    trials = list(dict.fromkeys(path for _, _, path in named[1:]))
    args.inputs, args.setup_names = [*trials, model], True
    subject = setup_outputs(args.scale_setup, None).model
    if args.output is None and subject is not None:
        args.output = str(subject.with_suffix(".urdf"))


def _setup_names(args, from_osim: bool, named, trial_paths: list[Path], osim: Path, mots: list[Path],
                 errors: list[Path]) -> tuple[Path, Path | None, list[Path], list[Path]]:
    """--setup-names: the subject .osim, its marker set file (None where the Scale setup names none), each trial's .mot
    and marker errors where the lab's Scale and IK setups have OpenSim write them (`named`: their
    calibrate.io.osim_setup.setup_outputs, None without setups; a trial no setup names keeps calibrate's names)."""
    if not from_osim:
        raise CalibrateError("--setup-names names the OpenSim outputs of an OpenSim base model; give the lab's .osim")
    if named is None:
        raise CalibrateError("--setup-names takes the names the lab's setups give; add --scale-setup and/or --ik-setup")
    if named.model is not None:
        if args.output is not None and Path(args.output).suffix.lower() == ".osim":
            raise CalibrateError(f"{args.output}: -o names the subject .osim and so does {args.scale_setup.name} "
                                 f"({named.model.name}, with --setup-names); give one of them")
        osim = named.model
    pairs = [named.outputs_of(t, m, e) for t, m, e in zip(trial_paths, mots, errors, strict=True)]
    return osim, named.markers, [m for m, _ in pairs], [e for _, e in pairs]


def _by_name(model, unknown: list[str]) -> dict[str, str]:
    """What calibrate makes of the unknown labels its names place (calibrate.calibration.hosts): a lab's joint centre
    added at its joint's centre and tied there (centre_labels: one per joint; the other points for that centre stay
    unknown, on its joint's segments), a medial marker on the segment its hinge hangs from -- as `inspect` says."""
    from ..calibration.hosts import centre_joint, centre_labels, medial_host

    tied = centre_labels(model, unknown)
    out = {lab: f"-> {j.name}'s centre (by its name: added there, a joint-centre marker)" for lab, j in tied.items()}
    for lab in unknown:
        if lab in tied:
            continue
        if (joint := centre_joint(model, lab)) is not None:
            first = next(k for k, j in tied.items() if j.name == joint.name)
            out[lab] = (f"unknown; names {joint.name}'s centre as {first} does, which is tied: placed on "
                        f"{joint.parent} or {joint.child} like any label")
        elif (medial := medial_host(model, lab)) is not None:
            out[lab] = f"unknown; {medial[1]}'s medial marker by its name: on {medial[0]}"
    return out


def write_timed(cal, **outputs):
    """cal.write(**outputs); returns cal with the time that took as times['write'] (what the summary shows)."""
    t0 = time.perf_counter()
    cal.write(**outputs)
    return replace(cal, times={**cal.times, "write": time.perf_counter() - t0})


class Timed:
    """Progress on stderr with the elapsed time, shown once the run has taken a second (a long step's
    announcement at once; solver iterations at most twice a second)."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.last = 0.0

    def __call__(self, msg: Progress) -> None:
        now = time.perf_counter() - self.t0
        if (now >= 1.0 or msg.long) and (msg.iteration is None or now - self.last >= 0.5):
            self.last = now
            progress_printer(f"  [{now:6.2f} s] {msg}")


def cmd_demo(args: argparse.Namespace) -> int:
    from ..calibration.evaluate import compare_to_truth
    from ..calibration.pipeline import calibrate
    from ..io.read import read_trial

    model, sim, paths, dt = run_simulation(args)
    trial = read_trial(paths["trial"])  # what a user would have: the trial file (C3D, or TRC past 65 535 frames)
    kind = {"gait": "gait", "overhead": "overhead"}.get(args.motion or "", "squat")
    kind = "realistic " + kind if args.realistic else kind
    progress_printer(f"simulated a {kind} trial in {dt:.2f} s -> {args.out}/; calibrating {model.path.name} to it...")
    t0 = time.perf_counter()
    with progress_for(False, 100, Timed) as say:
        cal = calibrate(model, trial, progress=say)
    t_cal = time.perf_counter() - t0
    cal = write_timed(cal, urdf=args.out / "subject.urdf", motion=args.out / "subject_motion.csv",
                       report=args.out / "subject_report.json", overwrite=True)
    cmp = compare_to_truth(cal, sim)
    gaps = float(np.isnan(trial.markers[..., 0]).mean())
    print(cal.text())
    print("")
    print(f"calibrate demo: {model.summary()}")
    print(f"trial   {paths['trial']}: {trial.n_frames} frames at {trial.rate:g} Hz, noise {args.noise_mm:g} mm, "
          f"gaps {100 * gaps:.1f} %; truth in {paths['truth']}")
    print(f"result  {args.out / 'subject.urdf'}, subject_motion.csv, subject_report.json")
    print("")
    print("truth vs estimate")
    print(f"  {'joint':14s} {'kind':9s} {'centre err (mm)':>16s} {'axis err (deg)':>15s}")
    for name, err in cmp.centre_error.items():
        ax = f"{cmp.axis_error_deg[name]:15.2f}" if name in cmp.axis_error_deg else f"{'':15s}"
        print(f"  {name:14s} {cmp.kinds[name]:9s} {1000 * err:16.2f} {ax}")
    print("  (hinge centre error: distance from the true axis line; medians over frames)")
    print(f"  marker RMS   start (seeded geometry) {1000 * marker_rms(cal.initial_residuals):.2f} mm -> calibrated "
          f"{1000 * cmp.marker_rms:.3f} mm; true model refitted (noise floor) {1000 * cmp.floor_rms:.3f} mm")
    print(f"  joint angles RMS vs truth {cmp.angle_rms_deg:.2f} deg ({cmp.angle_rms_offset_free_deg:.2f} deg "
          f"without each DoF's constant offset); true model refitted {cmp.floor_angle_rms_deg:.2f} deg")
    print(f"  time         calibration {t_cal:.2f} s (" + ", ".join(f"{k} {v:.2f}" for k, v in cal.times.items())
          + ")")
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    path: Path = args.file
    if path.suffix.lower() == ".xml":  # a lab's OpenSim Scale or IK setup: what calibrate takes from it
        from ..io.osim_setup import describe_setup

        print("\n".join(describe_setup(path)))
        return 0
    if path.suffix.lower() in (".urdf", ".osim"):
        from ..errors import NoMarkersError
        from ..model.model import load_model

        try:
            m = load_model(path, getattr(args, "marker_set", None))
            markerless = False
        except NoMarkersError:  # an OpenSim model whose markers come in a MarkerSet file: its structure all the same
            from ..io.osim import osim_to_urdf
            from ..model.model import Model

            text, info = osim_to_urdf(path, need_markers=False)
            m = Model(path, text=text)
            m.osim = info
            markerless = True
        print(m.summary() if not markerless else m.summary().replace(", 1 markers", ", no markers"))
        if markerless:
            print("  no markers on its bodies: give its marker set with --marker-set FILE.xml to calibrate with it")
        print(f"  {'joint':16s} {'kind':9s} {'parent -> child':28s} centre (m, parent frame)")
        for j in m.joints:
            c = " ".join(f"{x:+.4f}" for x in j.centre)
            print(f"  {j.name:16s} {j.kind:9s} {j.parent + ' -> ' + j.child:28s} {c}")
        if markerless:
            print_osim(m)
            return 0
        print("  markers per segment:")
        for s in m.segments:
            if s.markers:
                print(f"    {s.name:12s} {' '.join(s.markers)}")
        from ..problem.priors import JOINT_MARKER_RADIUS, joint_centre_markers

        ties = joint_centre_markers(m, m.parameters())
        if ties:
            print(f"  joint-centre markers (within {1000 * JOINT_MARKER_RADIUS:g} mm of a joint centre of their "
                  "segment: points computed at the centre, kept there; priors.joint_marker_mm):")
            print("    " + ", ".join(f"{m.markers[t.marker].name} ({m.joints[t.joint].name})" for t in ties))
        from ..problem.priors import PLACEHOLDER_RADIUS, placeholder_markers

        held = placeholder_markers(m, m.parameters())
        if held:
            print(f"  placeholder markers (within {1000 * PLACEHOLDER_RADIUS:g} mm of another marker of their segment: "
                  "a cluster left for OpenSim's marker placer; placed by the trials alone, priors.placeholder_mm):")
            print("    " + ", ".join(m.markers[k].name for k in held))
        if path.suffix.lower() == ".osim":  # OpenSim's <fixed> flags: what its marker placer keeps, calibrate does not
            from ..io.osim_info import fixed_flags

            flags = fixed_flags(path, getattr(args, "marker_set", None))
            fixed = [n for n in m.marker_names if flags.get(n)]
            if fixed:
                print(f"  fixed markers: {len(fixed)} of its {len(m.marker_names)} are <fixed> (OpenSim's marker "
                      "placer leaves those where the model puts them and moves the others to the static): calibrate "
                      "places every marker from the trials alike, each pulled towards the model's place by "
                      "priors.marker_mm")
                print("    " + ", ".join(fixed))
        from ..model.sides import side_mismatches

        sides = side_mismatches(m)
        if sides:
            print("  markers on the other side than their names say (the model's labels exchanged? a trial's marker "
                  "of that name would be fitted there):")
            for x in sides:
                print(f"    {x.text()}")
        from ..calibration.identifiability import trading_joints
        from ..io.osim_info import osim_info

        info = osim_info(m)  # an OpenSim model's locked coordinates (its subtalars in Rajagopal2016) end a trade
        trading = trading_joints(m, locked=info.locked if info is not None else ())
        bare = sorted({seg for seg, _ in trading.values()})
        if bare:
            print("  segments without markers between turning joints (their turns trade; a hinge the trials cannot "
                  "tell from its neighbour is locked at 0, docs/calibration.md):")
            for seg in bare:
                pair = [j for j, (sg, _) in trading.items() if sg == seg]
                print(f"    {seg:12s} {' / '.join(pair)}")
        print_osim(m)
        return 0
    from ..io.read import read_trial

    model_path = getattr(args, "model", None)
    if model_path is None and getattr(args, "markers", None) is not None:
        raise CalibrateError("--markers: give the model too (--model MODEL) to see what the labels become")
    t = read_trial(path)
    rows = list(zip(t.labels, np.isnan(t.markers[..., 0]).mean(axis=0), strict=True))
    became: dict[str, str] = {}
    if model_path is not None:
        from ..io.labels import declared_segments, load_marker_map, map_labels
        from ..model.model import load_model

        model = load_model(model_path, getattr(args, "marker_set", None))
        given = load_marker_map(args.markers) if args.markers else None
        declared_segments(given, model)  # (a segment the model lacks: refused as calibrate refuses it)
        mapped, mapping = map_labels(t, model.marker_names, given)
        # the rows: every trial label, and a model output the map or the model names, read as a marker (its note)
        rows = list(zip([m.trial_label for m in mapping], np.isnan(mapped.markers[..., 0]).mean(axis=0), strict=True))
        became = {m.trial_label: (f"-> {m.label} ({m.how})" if m.how != "unknown" else "unknown")
                  + (f"; {m.note}" if m.note else "") for m in mapping}
        became.update(_by_name(model, [m.trial_label for m in mapping if m.how == "unknown"]))
    print(f"{path}: {t.n_frames} frames at {t.rate:g} Hz ({t.n_frames / t.rate:.2f} s), {t.n_markers} markers, "
          f"first frame {t.first_frame} (0-based)" + (f", times {t.times[0]:g} to {t.times[-1]:g} s (a setup's "
                                                      "time_range counts in these)" if t.n_frames else ""))
    if (m := t.measurements) is not None:  # a Plug-in Gait session's subject measurements (PROCESSING)
        parts = ([f"mass {m.mass:g} kg"] if m.mass is not None else []) + \
            ([f"height {m.height:g} m"] if m.height is not None else []) + \
            [f"{j} width {1000 * w:g} mm" for j, w in sorted(m.widths.items())]
        print(f"  measured ({m.source}): " + ", ".join(parts))
    from ..calibration.pipeline import STILL_MOTION, relative_motion

    moves = relative_motion(t)  # which trial is the static (--neutral, --still-weight): the one that keeps still
    print(f"  motion: its markers keep their distances to {1000 * moves:.1f} mm SD (median over marker pairs): "
          + ("still, a static trial" if moves < STILL_MOTION else
             "a movement trial (a static keeps them to 0.4-1.6 mm)"))
    from ..io.labels import HOWS, SUBJECT_MARKERS
    from ..io.trial import subject_prefixes

    subjects = {k: n for k, n in subject_prefixes(t.labels).items() if n >= SUBJECT_MARKERS}
    if len(subjects) > 1:  # a session's file with each subject's markers (Vicon's Derrick:RASI, Viktor:RASI)
        print("  subjects: " + ", ".join(f"{k} ({n} labels)" for k, n in subjects.items())
              + ": calibrate one at a time (--subject NAME)")
    if became:
        hows = [m.how for m in mapping]
        named = sum(1 for m in mapping if m.how == "unknown" and m.trial_label in became
                    and "by its name" in became[m.trial_label])
        print(f"  labels against {model_path.name}'s {len(model.marker_names)} markers: "
              + ", ".join(f"{hows.count(h)} {h}" for h in HOWS if h in hows)
              + (f" ({named} of them read by their names: a joint's centre, a medial marker)" if named else "")
              + " (an unknown label is placed on a segment by rigidity, by its place on the model's poses, by its "
              "distances' margin to one segment's markers, or, in a rigid cluster, where a segment's unseen model "
              "markers would be, when "
              "calibrating, if one carries it; "
                "--markers map.toml names it)")
        if mapping.missing:
            print(f"  {model_path.name}'s markers the trial lacks ({len(mapping.missing)}): "
                  + ", ".join(mapping.missing))
    for lab, g in rows:
        said = (f"  '{t.descriptions[lab]}'" if lab in t.descriptions and "by its description" not in
                (became or {}).get(lab, "") else "")  # the file's own words for the marker
        print(f"  {lab:16s} gaps {100 * g:5.1f} %" + (f"  {became[lab]}" if became else "") + said)
    from ..calibration.plugin_gait import plugin_gait_knees

    for check, *_ in plugin_gait_knees(t):  # the file's Plug-in Gait bones, checked against their own motion
        print(f"  plug-in gait: {check.text()}" + (": misaligned (its femur frame turned about the thigh: a thigh "
                                                 "wand or KAD off the plane the knee flexes in)" if check.misaligned
                                                 else ""))
    return 0


def print_osim(model) -> None:
    """What an OpenSim import approximated, locked and dropped (nothing for a model not from a .osim)."""
    from ..io.osim_info import approximation_table, gimbal_text, osim_info

    info = osim_info(model)
    if info is None:
        return
    print(f"  imported from OpenSim model {info.source}; approximated joints:")
    print(approximation_table(info))
    if info.locked:
        print(f"  locked coordinates (held in every frame): {', '.join(info.locked)}")
    if info.dropped:
        print(f"  coordinates that are not degrees of freedom here: {', '.join(info.dropped)}")
    for coords, _ in info.gimbals:
        print(f"  gimbal: {gimbal_text(info, coords)}; a calibration holds their axes (--no-auto-hold frees them)")


def cmd_import_osim(args: argparse.Namespace) -> int:
    """``calibrate import-osim MODEL.osim [--marker-set XML] [-o URDF]``."""
    from ..io.text import atomic_write_text
    from ..model.model import load_model

    src: Path = args.model
    out: Path = args.output or src.with_suffix(".urdf")
    if out.suffix.lower() != ".urdf":
        raise CalibrateError(f"{out}: the output is a URDF; give it a .urdf name")
    check_targets([out], args.overwrite, exists_hint="pass --overwrite to replace it or choose another -o")
    model = load_model(src, args.marker_set)
    try:
        atomic_write_text(out, model.text)
    except OSError as e:
        raise CalibrateError(f"{out}: cannot write ({e.strerror}); choose a writable place") from None
    print(model.summary())
    print_osim(model)
    print(f"wrote {out}")
    return 0


def cmd_joints(args: argparse.Namespace) -> int:
    from ..io.labels import load_marker_map, map_labels
    from ..io.read import read_trial
    from ..model.model import load_model
    from ..seed.joints import estimate_model_joints, write_centres_csv

    out: Path | None = args.out
    if out is not None:
        if out.exists() and not args.overwrite:
            raise CalibrateError(f"{out}: already exists; pass --overwrite to replace it or choose another --out")
        if out.suffix.lower() in (".urdf", ".c3d", ".trc"):
            raise CalibrateError(f"{out}: --out is a CSV of joint centres; give it a .csv name")
        if not out.parent.exists() and str(out.parent) not in ("", "."):
            raise CalibrateError(f"{out}: directory {out.parent} does not exist; create it first")
    t0 = time.perf_counter()
    model = load_model(args.model)
    if not model.markers:
        raise CalibrateError(f"{args.model}: the model has no markers, so no segment can be followed; "
                             "add marker links (see docs/model-format.md)")
    trial = read_trial(args.trial)
    marker_map = load_marker_map(args.markers) if args.markers else None
    trial, mapping = map_labels(trial, model.marker_names, marker_map, aliases=not args.no_aliases)
    renamed = [m for m in mapping if m.how in ("map", "alias", "description")]
    if renamed:
        print(f"labels {len(renamed)} renamed to the model's: "
              + ", ".join(f"{m.trial_label} -> {m.label}" for m in renamed[:8]) + (" ..." if len(renamed) > 8 else ""))
    known = set(model.marker_names)
    used = [lab for lab in trial.labels if lab in known]
    unknown = [lab for lab in trial.labels if lab not in known]
    if not used:
        raise CalibrateError(f"{args.trial}: none of its {trial.n_markers} labels is a marker of {args.model} "
                             f"(e.g. '{trial.labels[0] if trial.labels else ''}'); rename the markers to the model's")
    load_s = time.perf_counter() - t0
    print(f"trial  {args.trial}: {trial.n_frames} frames at {trial.rate:g} Hz, {trial.n_markers} markers "
          f"({len(used)} in the model)")
    print(f"model  {args.model}: {len(model.segments)} segments, {len(model.joints)} joints, "
          f"{len(model.markers)} markers")
    from ..seed.association import associate_to_model, exchanged_between, misplaced_labels

    assoc = associate_to_model(model, trial)
    extra = {m.label: m.segment for m in assoc.markers if m.status == "assigned" and m.segment}
    if unknown:
        print(f"{len(unknown)} trial markers are not in the model; placed by rigidity with the segments' markers:")
        for lab in unknown:
            m = assoc[lab]
            where = f"-> {m.segment} (distance std {1000 * m.spread:.1f} mm)" if m.segment else f"left out: {m.reason}"
            print(f"  {lab:12s} {where}")
    for lab in assoc.suspects:
        print(f"warning: {lab} does not move rigidly with the other markers of {assoc[lab].segment} "
              f"({assoc[lab].reason}); is it mislabelled?", file=sys.stderr)
    for m in misplaced_labels(model, [trial]):  # a label exchanged for the whole trial (docs/calibration.md)
        print(f"warning: {m.text()}; check the label", file=sys.stderr)
    for x in exchanged_between(model, [trial]):  # two labels of one segment exchanged (against the base model's)
        print(f"warning: {x.text([args.trial.name])}; check the labels", file=sys.stderr)
    missing = [m for m in model.marker_names if m not in set(trial.labels)]
    if missing:
        print(f"warning: {len(missing)} model markers are not in the trial: {', '.join(missing)}", file=sys.stderr)
    cutoff = None if args.no_filter else args.cutoff_hz
    if cutoff is not None and cutoff >= trial.rate / 2:
        print(f"warning: --cutoff-hz {cutoff:g} is not below half the frame rate ({trial.rate / 2:g} Hz); "
              "markers are not filtered", file=sys.stderr)
        cutoff = None
    est = estimate_model_joints(model, trial, mode=args.mode, cutoff_hz=cutoff, extra_markers=extra)
    print("")
    print(est.table())
    print("")
    n_ok = sum(j.ok for j in est)
    methods = {m: sum(j.method == m for j in est) for m in ("MTB", "MTB (propagated)", "JMV")}
    filt = f"low-passed at {cutoff:g} Hz" if cutoff else "unfiltered"
    print(f"{n_ok}/{len(est)} joints estimated (" + ", ".join(f"{v} {k}" for k, v in methods.items() if v)
          + f") in {est.seconds:.2f} s; markers {filt}; load {load_s:.2f} s")
    print("resid mm: RMS change of the joint-to-marker distances over the trial (0 for a perfect rigid joint; "
          "about the marker noise for a good estimate).")
    if out is not None:
        write_centres_csv(out, est, overwrite=True)
        print(f"wrote {out}")
    return 0 if n_ok == len(est) else 1
