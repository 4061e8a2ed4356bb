"""Command line: ``calibrate TRIAL [TRIAL ...] MODEL`` (calibrate a subject), ``calibrate simulate``,
``calibrate demo``, ``calibrate inspect``, ``calibrate joints``, ``calibrate export-osim``, ``calibrate export-mjcf``,
``calibrate report`` (HTML report), ``calibrate view`` (3-D view).

A thin layer over the Python API.  Bad input gives one line on stderr
(``calibrate: error: ...``) and exit status 2; nothing half-written.
"""

from __future__ import annotations

import argparse
import atexit
import os
import sys
import warnings
from pathlib import Path

from calibrate.cli.args import (
    count_arg,
    fraction_arg,
    frames_arg,
    height_arg,
    int_at_least,
    nonneg_float,
    positive_float,
    positive_int,
)
from calibrate.cli.commands import cmd_calibrate, cmd_demo, cmd_import_osim, cmd_inspect, cmd_joints, cmd_simulate
from calibrate.cli.track import add_track_parser, cmd_track

from ..errors import CalibrateError


def _add_sim_args(p: argparse.ArgumentParser, frames: int) -> None:
    p.add_argument("--frames", type=positive_int, default=frames, help=f"number of frames (default {frames})")
    p.add_argument("--rate", type=positive_float, default=100.0, help="frame rate in Hz (default 100)")
    p.add_argument("--noise-mm", type=nonneg_float, default=1.0, help="marker noise SD in mm (default 1)")
    p.add_argument("--gaps", action="store_true", help="add realistic occlusion gaps")
    p.add_argument("--gap-fraction", type=fraction_arg, default=None, metavar="F",
                   help="occlusion gaps (0.05-0.6 s each) covering fraction F of the marker samples, e.g. 0.05")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--motion", choices=("squats", "gait", "overhead"), default=None,
                   help="squats (every joint through a wide arc), treadmill gait (normal walking ranges: "
                        "forearms, wrists, neck and subtalar joints hardly move) or overhead (serve- and "
                        "throw-like arm arcs to 155-172 deg of shoulder abduction or flexion, the rest of the "
                        "body in smaller squat-like arcs); default squats")
    p.add_argument("--sta-mm", type=nonneg_float, default=None, metavar="X",
                   help="soft-tissue artefact: skin markers move relative to their bones with the joint angles, "
                        "X mm at the shank, 2X at the thigh, by segment (docs/simulation.md); default 0")
    p.add_argument("--height", type=height_arg, default=None, metavar="M",
                   help="the subject's stature in m (0.9-2.2), segment proportions varied by +-4 %%")
    p.add_argument("--swaps", type=count_arg, default=None, metavar="N",
                   help="N episodes of 3-10 frames with two neighbouring markers' labels exchanged")
    p.add_argument("--spikes", type=count_arg, default=None, metavar="N",
                   help="N single-frame gross errors of 30-100 mm on random markers (swapped and spiked samples "
                        "are listed in OUT/truth_corruptions.csv)")
    p.add_argument("--realistic", action="store_true",
                   help="as a lab records it: overhead arm arcs with every joint through ~70 %% of its range, "
                        "--sta-mm 3, a random stature of 1.5-2.0 m, --gap-fraction 0.05, --swaps 3, --spikes 5, "
                        "1 mm noise; the flags above override")
    p.add_argument("--model", type=Path, default=None,
                   help="base model, a URDF or an OpenSim .osim (default: models/human.urdf)")
    p.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                   help="an OpenSim MarkerSet file's markers added to an .osim --model (replacing those of the same "
                        "name), as calibrate's --marker-set")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: 'calibrate simulate: error: ...; see --help', exit 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def _top(usage: str, description: str) -> _Parser:
    """A parser of the program itself, 'calibrate' (its commands, or the calibration its arguments ask for)."""
    return _Parser(prog="calibrate", usage=usage, description=description)


class _Version(argparse.Action):
    """--version: calibrate's version and those of Python and the libraries it runs on (calibrate.software), looked
    up only when asked."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs) -> None:  # noqa: ANN003
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: ANN001
        from ..software import version_line

        print(version_line())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    ap = _top("calibrate TRIAL [TRIAL ...] MODEL [options]   (see 'calibrate TRIAL MODEL --help')\n"
              "       calibrate COMMAND ...",
              "Subject-specific human models from motion-capture trials.  'calibrate TRIAL [TRIAL ...] "
              "MODEL' calibrates MODEL to the subject of the trials; the commands below help around it.")
    ap.add_argument("--version", action=_Version,
                    help="print calibrate's version and those of Python and the libraries it runs on, and exit")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser, prog="calibrate")
    sim = sub.add_parser("simulate", help="write a synthetic squat, gait or overhead trial with its truth",
                         description="Simulate squats (or treadmill gait, --motion gait, or overhead arm arcs, "
                                     "--motion overhead) of a random synthetic subject derived from a base model; "
                                     "writes OUT/trial.c3d, OUT/truth.urdf and OUT/truth_motion.csv (and "
                                     "OUT/truth_corruptions.csv with --swaps/--spikes).  What a lab adds: "
                                     "--sta-mm, --height, --gap-fraction, --swaps, --spikes, or --realistic.")
    sim.add_argument("--out", type=Path, required=True, help="output directory (created if missing)")
    sim.add_argument("--overwrite", action="store_true", help="replace trial.c3d/truth.urdf/truth_motion.csv in OUT")
    sim.add_argument("--cameras", type=int_at_least(2), nargs="?", const=8, default=None, metavar="N",
                     help="also N synthetic cameras around the volume (--cameras alone: 8): OUT/cameras.toml, the "
                          "unlabelled 2-D detections OUT/detections.npz and OUT/truth_detections.npz, the input "
                          "of 'calibrate track' (docs/tracking.md)")
    _add_sim_args(sim, 1000)
    demo = sub.add_parser("demo", help="simulate squats, calibrate the base model to them, compare with the truth",
                          description="Simulate a squat trial of a synthetic subject into ./calibrate-demo/ (its "
                                      "files are replaced on every run), calibrate the base model to it, and print "
                                      "truth vs estimate: joint-centre and axis errors, marker RMS, time.")
    demo.add_argument("--out", type=Path, default=Path("calibrate-demo"), help="output directory")
    _add_sim_args(demo, 1000)
    ins = sub.add_parser("inspect", help="describe a model (.urdf, .osim), a trial (.c3d/.trc, a Qualisys .tsv or "
                                         "Motive .csv) or an OpenSim Scale or IK setup (.xml)")
    ins.add_argument("file", type=Path, help="a .urdf, .osim, .c3d, .trc, .tsv, .csv or OpenSim setup .xml file")
    ins.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                     help="with a .osim: an OpenSim MarkerSet file whose markers are added (as the Scale tool does)")
    ins.add_argument("--model", type=Path, default=None, metavar="MODEL",
                     help="with a trial: what each of its labels becomes against MODEL's markers (exact, --markers "
                          "map, built-in alias, unknown) and which of MODEL's markers it lacks, before calibrating")
    ins.add_argument("--markers", type=Path, default=None, metavar="TOML",
                     help="with --model: the marker map a calibration would be given (model label = [trial labels])")
    jo = sub.add_parser("joints", help="joint-centre trajectories of a trial (MTB framework)",
                        description="Estimate every joint centre of MODEL's topology, frame by frame, from TRIAL's "
                                    "markers alone (marker-trajectory bases, solvability propagation, JMV fallback; "
                                    "hinge axes by closed-form fit).  Prints a table per joint; --out writes the "
                                    "trajectories as CSV (m).")
    jo.add_argument("trial", type=Path, help="trial (.c3d, .trc, Qualisys .tsv or Motive .csv)")
    jo.add_argument("model", type=Path, help="base model (.urdf): marker groups, joint tree, hinge priors")
    jo.add_argument("--out", type=Path, default=None, help="write the centre trajectories to this CSV")
    jo.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    jo.add_argument("--cutoff-hz", type=positive_float, default=6.0,
                    help="low-pass the markers at this frequency first (default 6 Hz)")
    jo.add_argument("--no-filter", action="store_true", help="use the raw markers (no low-pass)")
    jo.add_argument("--markers", type=Path, default=None,
                    help="marker map (TOML: model label = [trial labels]) for labels the built-in aliases miss")
    jo.add_argument("--no-aliases", action="store_true",
                    help="do not rename common label spellings (R.ASIS, RASIS, ...) to the model's labels")
    jo.add_argument("--mode", choices=("framework", "jmv"), default="framework",
                    help="'framework' (default) or 'jmv': every joint by per-frame JMV only (slow baseline)")
    from ..io.mjcf import add_export_mjcf_parser
    from ..io.osim_export import add_export_osim_parser

    add_export_osim_parser(sub)
    add_export_mjcf_parser(sub)
    add_track_parser(sub)
    from calibrate.cli.ik import add_ik_parser

    add_ik_parser(sub)

    from calibrate.cli.batch import add_batch_parser
    from calibrate.cli.report import add_report_parsers

    add_report_parsers(sub)
    add_batch_parser(sub)
    io = sub.add_parser("import-osim", help="write an OpenSim model (.osim) as a calibrate model URDF",
                        description="Read an OpenSim 4 model (and optionally a MarkerSet file) and write it in "
                                    "calibrate's model format; lists what the format could only approximate "
                                    "(docs/opensim.md).  Nothing is written on an error.")
    io.add_argument("model", type=Path, metavar="MODEL.osim", help="the OpenSim model")
    io.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                    help="an OpenSim MarkerSet file whose markers are added, replacing those of the same name")
    io.add_argument("-o", "--output", type=Path, default=None, metavar="URDF",
                    help="the URDF to write (default: MODEL's name + .urdf)")
    io.add_argument("--overwrite", action="store_true", help="replace the output if it exists")
    return ap


COMMANDS = ("simulate", "demo", "inspect", "joints", "export-osim", "export-mjcf", "import-osim", "track", "report",
            "view", "batch", "ik")


def build_calibrate_parser() -> argparse.ArgumentParser:
    ap = _top("calibrate TRIAL [TRIAL ...] MODEL [-o URDF] [--motion CSV] [--report JSON] [--markers TOML] ...\n"
              "       calibrate --scale-setup XML [--ik-setup XML ...] [options]   (the lab's OpenSim setups alone)\n"
              f"       calibrate {{{','.join(COMMANDS)}}} ...",
              "Calibrate MODEL (a URDF, or an OpenSim model .osim) to the subject of one or more TRIALs "
              "(.c3d or .trc, or Qualisys QTM's .tsv or OptiTrack Motive's .csv export; e.g. a static "
              "trial and movement trials): segment scales, joint centres, hinge axes and marker positions "
              "shared by all trials, with every frame's pose, in one least-squares problem.  Writes the "
              "subject URDF, a motion CSV per trial and a report JSON next to the first trial (or beside -o's "
              f"URDF).  Other commands: {', '.join(COMMANDS)} (see 'calibrate COMMAND --help').")
    ap.add_argument("inputs", type=Path, nargs="*", metavar="TRIAL ... MODEL",
                    help="the trials (.c3d, .trc, .tsv or .csv), then the base model (.urdf or .osim) to calibrate "
                         "(never modified); none with --scale-setup: the generic model and static trial it names and "
                         "the trial each --ik-setup names, the outputs where they name them (--setup-names), as "
                         "OpenSim's Scale and IK tools run them")
    ap.add_argument("-o", "--output", type=str, default=None,
                    help="subject URDF (default: the first TRIAL's name + .urdf); from an OpenSim base model, "
                         "NAME.osim names the subject .osim too (both written, side by side); a folder (results/): "
                         "every output in it, under the first TRIAL's name")
    ap.add_argument("--motion", type=Path, default=None,
                    help="motion CSV of a single trial (default: TRIAL's name + _motion.csv, for each trial, "
                         "beside -o's URDF if given, else beside the trial)")
    ap.add_argument("--report", type=Path, default=None,
                    help="report JSON (default: the first TRIAL's name + _report.json, beside -o's URDF if given, "
                         "else beside the trial)")
    ap.add_argument("--html", type=Path, default=None, metavar="HTML",
                    help="also write the HTML report (one offline file; docs/report.md), e.g. report.html")
    ap.add_argument("--c3d", action="store_true",
                    help="also write each trial as TRIAL-name_calibrated.c3d beside its motion: its markers with "
                         "calibrate's joint centres (<joint>_JC), model markers (<marker>_model) and joint angles "
                         "(<joint>_angles, deg) as model outputs, for Mokka, Nexus or Visual3D")
    ap.add_argument("--mjcf", action="store_true",
                    help="also write the subject as a MuJoCo model (URDF-name_mujoco.xml beside it) and each motion "
                         "as MuJoCo qpos rows (motion-name_qpos.csv beside it); docs/mujoco.md")
    ap.add_argument("--frames", type=frames_arg, default=None,
                    help="use frames A:B only (0-based, B excluded; a single trial only)")
    ap.add_argument("--markers", type=Path, default=None,
                    help="marker map (TOML: model label = [trial labels]) for labels the built-in aliases miss; its "
                         "[segments] table (segment = [trial labels]) puts labels the model lacks on those segments")
    ap.add_argument("--subject", default=None, metavar="NAME",
                    help="of trials holding several subjects' markers (Vicon's NAME:RASI), calibrate NAME's")
    ap.add_argument("--no-aliases", action="store_true",
                    help="do not rename common label spellings (R.ASIS, RASIS, ...) to the model's labels")
    ap.add_argument("--no-new-markers", action="store_true",
                    help="ignore trial markers the model does not know (default: place them on segments and fit)")
    ap.add_argument("--outlier-sigmas", type=nonneg_float, default=None,
                    help="reject marker positions further than this many noise SDs from the fit (default 6; 0: off)")
    ap.add_argument("--config", type=Path, default=None, help="settings file (TOML; see docs/calibration.md)")
    ap.add_argument("--free", default=None,
                    help="comma-separated parameter groups to calibrate: scale,centre,axis,marker (default all)")
    ap.add_argument("--loss", choices=("linear", "huber", "cauchy"), default=None,
                    help="robust loss against marker outliers (default linear)")
    ap.add_argument("--noise-mm", type=positive_float, default=None,
                    help="marker noise SD in mm, kept as given (default: learnt per marker from the residuals)")
    ap.add_argument("--no-learn-noise", action="store_true",
                    help="do not learn the markers' noise SDs from the residuals; use --noise-mm (default 1) for all")
    ap.add_argument("--still-weight", type=float, default=None, metavar="FRAMES",
                    help="what a still (static) trial counts as, in frames in all, beside a trial that moves "
                         "(default 0: every frame once; 16 fits the walk's new frames better, docs/calibration.md)")
    ap.add_argument("--no-seed", action="store_true", help="start from the base model, not from MTB joint centres")
    ap.add_argument("--lock", default=None, metavar="DOF[=DEG],...",
                    help="hold coordinates at a value (default 0 deg) in every frame, e.g. "
                         "subtalar_r,subtalar_l: what the marker set cannot resolve (as OpenSim's locked coordinates)")
    ap.add_argument("--hold-axes", default=None, metavar="DOF,...",
                    help="keep these hinge/universal axes at the base model's (their angles stay free)")
    ap.add_argument("--hold-centres", default=None, metavar="JOINT,...",
                    help="keep each of these joints' centres at the base model's offset from the markers of the "
                         "segment it is expressed in, at the size of those markers' layout (a joint the trials "
                         "barely turn, e.g. a walk's lumbar joint 'back', whose fitted centre the summary calls "
                         "implausible)")
    ap.add_argument("--moved-markers", action="store_true",
                    help="leave out a static trial's positions of markers it shows elsewhere on their segment than "
                         "the moving trials do (a slipped cluster, an acromion marker lifted with the arms); the "
                         "model keeps the moving trials' place and the summary names them")
    ap.add_argument("--keep-far-joints", action="store_true",
                    help="keep a static trial's markers beyond a joint it holds where the moving trials never go "
                         "(by default left out: arms out in the static, at the sides in the walk; a shoulder "
                         "without its blade cannot be both; a model whose shoulder blade moves can)")
    hips = ap.add_mutually_exclusive_group()
    hips.add_argument("--hip-regression", action="store_true",
                      help="place the hip centres by Harrington's regression from the pelvis markers (ASIS, PSIS or "
                           "sacrum), as gait labs do where no functional hip trial places them: a walk does not")
    hips.add_argument("--hip-regression-auto", action="store_true",
                      help="calibrate without the regression, and again with it where that leaves a hip implausible "
                           "(over 40 mm from the regression, or the hips wider apart than 0.9 times the ASIS "
                           "markers, where the trials' motion does not place them; wider apart than the ASIS "
                           "markers or closer together than half their width, wherever): a second calibration only "
                           "there, kept unless it fits the markers over 1.25 times worse with the hips inside the "
                           "pelvis; the summary and report say which (settings file: hip_regression = \"auto\"; by "
                           "default only where the hips end wider apart than the ASIS markers or closer together "
                           "than half their width, outside the pelvis or on its midline: "
                           "hip_regression = \"outside\")")
    hips.add_argument("--no-hip-regression", action="store_true",
                      help="never place the hips by Harrington's regression, not even where the calibration leaves "
                           "them wider apart than the ASIS markers or closer together than half their width (by "
                           "default it calibrates again with it there; "
                           "settings file: hip_regression = false)")
    ap.add_argument("--no-auto-hold", action="store_true",
                    help="calibrate the axes of coordinates the trial does not show moving too (and of those it "
                         "turns through less than 20 deg where the fit carried the axis far), the centres of ball "
                         "joints it turns through less than 20 deg where the fit carried the centre far, and in a "
                         "static alone the hips', shoulders' and lumbar joint's centres (by default they are held at "
                         "the base model's, and the summary says which)")
    ap.add_argument("--segment-frames", choices=("markers", "priors"), default=None,
                    help="where the segment frames end, in which the joint angles are read: 'markers' (turned to "
                         "where each segment's markers put them, as the model defines them) or 'priors' (where the "
                         "priors hold the geometry least); default: markers for an OpenSim model, else priors")
    ap.add_argument("--memory-mb", type=positive_float, default=None, metavar="MB",
                    help="memory for the frames' normal-equation blocks at once (default 200; ~170 kB per frame "
                         "for the full body): a longer trial's are formed chunk by chunk, in bounded memory")
    ap.add_argument("--neutral", type=int_at_least(1), default=None, metavar="K",
                    help="trial K (1 = the first) shows the subject standing in the model's neutral pose (a static "
                         "trial): segment frames are turned so that its joint angles are zero")
    ap.add_argument("--mass", type=positive_float, default=None,
                    help="subject's body mass in kg: segment masses and inertias are the base model's scaled to "
                         "it (default: the base model's masses kept)")
    ap.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                    help="with an OpenSim MODEL.osim: an OpenSim MarkerSet file whose markers are added, replacing "
                         "those of the same name (as OpenSim's Scale tool does)")
    ap.add_argument("--scale-setup", type=Path, default=None, metavar="XML",
                    help="with an OpenSim MODEL.osim: the lab's OpenSim Scale setup file (e.g. "
                         "subject01_Setup_Scale.xml), for the subject's body mass and the marker set it names (--mass "
                         "and --marker-set win), and the static's time range its scaler and marker placer use "
                         "(docs/opensim.md)")
    ap.add_argument("--ik-setup", type=Path, default=None, metavar="XML", action="append",
                    help="a lab's OpenSim IK setup file (e.g. subject01_Setup_IK.xml): the coordinates its coordinate "
                         "tasks hold (Gait2392's subtalar and mtp angles) are locked at their values, as its IK "
                         "holds them (--lock overrides), and its trial is cut to its time range; repeat it for "
                         "each trial's setup (docs/opensim.md)")
    ap.add_argument("--whole-trials", action="store_true",
                    help="use every frame of the trials, not the time ranges --scale-setup and --ik-setup name")
    ap.add_argument("--setup-names", action="store_true",
                    help="write the subject .osim, the motions (.mot) and the marker errors (.sto) under the names and "
                         "in the folders the --scale-setup and --ik-setup files have OpenSim write them (each read "
                         "against its setup's folder), where the lab's later setups (ID, Static Optimization, CMC) "
                         "look for them")
    ap.add_argument("--overwrite", action="store_true", help="replace existing output files")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    return ap


def _calibrating(argv: list[str]) -> bool:
    """Whether `argv` asks to calibrate a subject (`calibrate TRIAL ... MODEL`), not a sub-command."""
    first = next((a for a in argv if not a.startswith("-")), None)
    return first is not None and first not in COMMANDS and not any(a in ("-h", "--help") for a in argv[:1])


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if _calibrating(argv):
        args = build_calibrate_parser().parse_args(argv)
        return _guard(cmd_calibrate, args)
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.command is None:
        ap.print_help()
        return 2
    from ..io.mjcf import cmd_export_mjcf
    from ..io.osim_export import cmd_export_osim
    from .batch import cmd_batch
    from .ik import cmd_ik
    from .report import cmd_report, cmd_view

    commands = {"report": cmd_report, "view": cmd_view, "batch": cmd_batch,
                "simulate": cmd_simulate, "demo": cmd_demo, "inspect": cmd_inspect, "joints": cmd_joints,
                "export-osim": cmd_export_osim, "export-mjcf": cmd_export_mjcf, "import-osim": cmd_import_osim,
                "track": cmd_track, "ik": cmd_ik}
    return _guard(commands[args.command], args)


def run() -> None:
    """The `calibrate` program (console script and ``python -m calibrate.cli``): main(), and after a
    calibration out at once.  Python's teardown then frees every module and object one by one, 0.1 s
    of a 4.5 s run on pig_walk; the outputs are written and closed by then, the worker threads idle and
    any child reaped.  The exit handlers still run.  Under a profiler or tracer (cProfile, coverage)
    Python ends as usual, so that theirs can report.  Output piped into a reader that stops early
    (``calibrate inspect model.osim | head``) ends the program quietly, as Unix tools do."""
    try:
        code = main()
    except BrokenPipeError:
        # Python's own flush of stdout at exit would raise again: point stdout at /dev/null first.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        os._exit(141)  # 128 + SIGPIPE, what a shell reports for a tool the pipe closed on
    if _calibrating(sys.argv[1:]) and sys.getprofile() is None and sys.gettrace() is None:
        sys.stdout.flush()
        sys.stderr.flush()
        atexit._run_exitfuncs()
        os._exit(code or 0)
    sys.exit(code)


#: numpy's words for a reduction over no finite value (a marker gap through every frame of a window): the
#: arithmetic on the trials' gaps, not a warning a user can act on.
_GAP_ARITHMETIC = ("All-NaN slice", "Mean of empty slice", "Degrees of freedom <= 0", "invalid value encountered")


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:  # noqa: ANN001
    """A warning as the command line says it, one line on stderr ('warning: ...'; calibrate's own, such as a
    LabelConflictWarning, by their text alone), not Python's file, line number and source; numpy's on the gaps
    of a trial (_GAP_ARITHMETIC) not at all."""
    text = str(message)
    if issubclass(category, RuntimeWarning) and text.startswith(_GAP_ARITHMETIC):
        return
    ours = str(getattr(category, "__module__", "")).startswith("calibrate")
    print(f"warning: {text}" if ours else f"warning: {category.__name__}: {text}", file=sys.stderr)


def _guard(command, args: argparse.Namespace) -> int:
    """Run a command; one-line errors (exit 2) for bad input, one-line warnings (_show_warning)."""
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return command(args)
    except CalibrateError as e:
        print(f"calibrate: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calibrate: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
