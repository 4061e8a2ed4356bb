"""Command line: ``calibrate TRIAL [TRIAL ...] MODEL`` (calibrate a subject), ``calibrate simulate``,
``calibrate demo``, ``calibrate inspect``, ``calibrate joints``, ``calibrate export-osim``.

A thin layer over the Python API.  Bad input gives one line on stderr
(``calibrate: error: ...``) and exit status 2; nothing half-written.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from .calibration.records import Progress
from .errors import CalibrateError
from .io.outputs import check_targets
from .seed.geometry import marker_rms

DEFAULT_MODEL = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


def _int_at_least(least: int) -> Callable[[str], int]:
    """An argparse type: a whole number >= `least`."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
        if v < least:
            raise argparse.ArgumentTypeError(f"need at least {least}, got {v}")
        return v
    return parse


_positive_int = _int_at_least(2)  # frame counts and the like


def _lock_arg(text: str) -> dict[str, float]:
    """'subtalar_r,ankle_l=10' -> {'subtalar_r': 0.0, 'ankle_l': 10.0} (degrees)."""
    out: dict[str, float] = {}
    for item in (x.strip() for x in text.split(",")):
        if not item:
            continue
        name, _, deg = item.partition("=")
        try:
            out[name.strip()] = float(deg) if deg.strip() else 0.0
        except ValueError:
            raise CalibrateError(f"--lock {text}: '{deg}' is not an angle in degrees (use DOF or DOF=DEG)") from None
    return out


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (v > 0 and np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be positive, got {text}")
    return v


def _nonneg_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got '{text}'") from None
    if not (v >= 0 and np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"must be zero or positive, got {text}")
    return v


def _count(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be zero or positive, got {v}")
    return v


def _height_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a stature in metres, got '{text}'") from None
    if not (1.4 <= v <= 2.2):
        raise argparse.ArgumentTypeError(f"must be a stature of 1.4-2.2 m, got {text}")
    return v


def _fraction_arg(text: str) -> float:
    try:
        v = float(text[:-1]) / 100 if text.endswith("%") else float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a fraction such as 0.05 or 5%, got '{text}'") from None
    if not (0 <= v <= 0.5):
        raise argparse.ArgumentTypeError(f"must be a fraction of 0-0.5 (0-50 %), got {text}")
    return v


def _default_model() -> Path:
    """models/human.urdf of the source tree; in an installed package (no source tree) the same
    model is generated from calibrate.model.human into the temporary directory."""
    if DEFAULT_MODEL.exists():
        return DEFAULT_MODEL
    import tempfile

    from .model.human import build_human_urdf

    path = Path(tempfile.gettempdir()) / "calibrate-human.urdf"
    text = build_human_urdf()
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _add_sim_args(p: argparse.ArgumentParser, frames: int) -> None:
    p.add_argument("--frames", type=_positive_int, default=frames, help=f"number of frames (default {frames})")
    p.add_argument("--rate", type=_positive_float, default=100.0, help="frame rate in Hz (default 100)")
    p.add_argument("--noise-mm", type=_nonneg_float, default=1.0, help="marker noise SD in mm (default 1)")
    p.add_argument("--gaps", action="store_true", help="add realistic occlusion gaps")
    p.add_argument("--gap-fraction", type=_fraction_arg, default=None, metavar="F",
                   help="occlusion gaps (0.05-0.6 s each) covering fraction F of the marker samples, e.g. 0.05")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--motion", choices=("squats", "gait", "overhead"), default=None,
                   help="squats (every joint through a wide arc), treadmill gait (normal walking ranges: "
                        "forearms, wrists, neck and subtalar joints hardly move) or overhead (serve- and "
                        "throw-like arm arcs to 155-172 deg of shoulder abduction or flexion, the rest of the "
                        "body in smaller squat-like arcs); default squats")
    p.add_argument("--sta-mm", type=_nonneg_float, default=None, metavar="X",
                   help="soft-tissue artefact: skin markers move relative to their bones with the joint angles, "
                        "X mm at the shank, 2X at the thigh, by segment (docs/simulation.md); default 0")
    p.add_argument("--height", type=_height_arg, default=None, metavar="M",
                   help="the subject's stature in m (1.4-2.2), segment proportions varied by +-4 %%")
    p.add_argument("--swaps", type=_count, default=None, metavar="N",
                   help="N episodes of 3-10 frames with two neighbouring markers' labels exchanged")
    p.add_argument("--spikes", type=_count, default=None, metavar="N",
                   help="N single-frame gross errors of 30-100 mm on random markers (swapped and spiked samples "
                        "are listed in OUT/truth_corruptions.csv)")
    p.add_argument("--realistic", action="store_true",
                   help="as a lab records it: overhead arm arcs with every joint through ~70 %% of its range, "
                        "--sta-mm 3, a random stature of 1.5-2.0 m, --gap-fraction 0.05, --swaps 3, --spikes 5, "
                        "1 mm noise; the flags above override")
    p.add_argument("--model", type=Path, default=None, help="base model URDF (default: models/human.urdf)")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: 'calibrate simulate: error: ...; see --help', exit 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(
        prog="calibrate",
        usage="calibrate TRIAL [TRIAL ...] MODEL [options]   (see 'calibrate TRIAL MODEL --help')\n"
              "       calibrate COMMAND ...",
        description="Subject-specific human models from motion-capture trials.  'calibrate TRIAL [TRIAL ...] "
                    "MODEL' calibrates MODEL to the subject of the trials; the commands below help around it.",
    )
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser, prog="calibrate")
    sim = sub.add_parser("simulate", help="write a synthetic squat, gait or overhead trial with its truth",
                         description="Simulate squats (or treadmill gait, --motion gait, or overhead arm arcs, "
                                     "--motion overhead) of a random synthetic subject derived from a base model; "
                                     "writes OUT/trial.c3d, OUT/truth.urdf and OUT/truth_motion.csv (and "
                                     "OUT/truth_corruptions.csv with --swaps/--spikes).  What a lab adds: "
                                     "--sta-mm, --height, --gap-fraction, --swaps, --spikes, or --realistic.")
    sim.add_argument("--out", type=Path, required=True, help="output directory (created if missing)")
    sim.add_argument("--overwrite", action="store_true", help="replace trial.c3d/truth.urdf/truth_motion.csv in OUT")
    _add_sim_args(sim, 1000)
    demo = sub.add_parser("demo", help="simulate squats, calibrate the base model to them, compare with the truth",
                          description="Simulate a squat trial of a synthetic subject into ./calibrate-demo/ (its "
                                      "files are replaced on every run), calibrate the base model to it, and print "
                                      "truth vs estimate: joint-centre and axis errors, marker RMS, time.")
    demo.add_argument("--out", type=Path, default=Path("calibrate-demo"), help="output directory")
    _add_sim_args(demo, 1000)
    ins = sub.add_parser("inspect", help="describe a model (.urdf, .osim) or a trial (.c3d/.trc)")
    ins.add_argument("file", type=Path, help="a .urdf, .osim, .c3d or .trc file")
    ins.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                     help="with a .osim: an OpenSim MarkerSet file whose markers are added (as the Scale tool does)")
    jo = sub.add_parser("joints", help="joint-centre trajectories of a trial (MTB framework)",
                        description="Estimate every joint centre of MODEL's topology, frame by frame, from TRIAL's "
                                    "markers alone (marker-trajectory bases, solvability propagation, JMV fallback; "
                                    "hinge axes by closed-form fit).  Prints a table per joint; --out writes the "
                                    "trajectories as CSV (m).")
    jo.add_argument("trial", type=Path, help="trial (.c3d or .trc)")
    jo.add_argument("model", type=Path, help="base model (.urdf): marker groups, joint tree, hinge priors")
    jo.add_argument("--out", type=Path, default=None, help="write the centre trajectories to this CSV")
    jo.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    jo.add_argument("--cutoff-hz", type=_positive_float, default=6.0,
                    help="low-pass the markers at this frequency first (default 6 Hz)")
    jo.add_argument("--no-filter", action="store_true", help="use the raw markers (no low-pass)")
    jo.add_argument("--markers", type=Path, default=None,
                    help="marker map (TOML: model label = [trial labels]) for labels the built-in aliases miss")
    jo.add_argument("--no-aliases", action="store_true",
                    help="do not rename common label spellings (R.ASIS, RASIS, ...) to the model's labels")
    jo.add_argument("--mode", choices=("framework", "jmv"), default="framework",
                    help="'framework' (default) or 'jmv': every joint by per-frame JMV only (slow baseline)")
    from .io.osim_export import add_export_osim_parser

    add_export_osim_parser(sub)
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


COMMANDS = ("simulate", "demo", "inspect", "joints", "export-osim", "import-osim")


def _frames_arg(text: str) -> slice:
    """'A:B' (0-based, B excluded, either side optional) -> slice."""
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        a = int(parts[0]) if parts[0].strip() else None
        b = int(parts[1]) if parts[1].strip() else None
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected A:B (0-based frame indices, B excluded), got '{text}'") from None
    if (a is not None and a < 0) or (b is not None and b < 0):
        raise argparse.ArgumentTypeError(f"frame indices must be 0 or more, got '{text}'")
    return slice(a, b)


def build_calibrate_parser() -> argparse.ArgumentParser:
    ap = _Parser(
        prog="calibrate",
        usage="calibrate TRIAL [TRIAL ...] MODEL [-o URDF] [--motion CSV] [--report JSON] [--markers TOML] ...\n"
              "       calibrate {simulate,demo,inspect,joints,export-osim} ...",
        description="Calibrate MODEL (a URDF) to the subject of one or more TRIALs (.c3d or .trc; e.g. a static "
                    "trial and movement trials): segment scales, joint centres, hinge axes and marker positions "
                    "shared by all trials, with every frame's pose, in one least-squares problem.  Writes the "
                    "subject URDF, a motion CSV per trial and a report JSON next to the first trial.  Other "
                    "commands: simulate, demo, inspect, joints, export-osim (see 'calibrate COMMAND --help').")
    ap.add_argument("inputs", type=Path, nargs="+", metavar="TRIAL ... MODEL",
                    help="the trials (.c3d or .trc), then the base model (.urdf) to calibrate (never modified)")
    ap.add_argument("-o", "--output", type=Path, default=None,
                    help="subject URDF (default: the first TRIAL's name + .urdf)")
    ap.add_argument("--motion", type=Path, default=None,
                    help="motion CSV of a single trial (default: TRIAL's name + _motion.csv, for each trial)")
    ap.add_argument("--report", type=Path, default=None,
                    help="report JSON (default: the first TRIAL's name + _report.json)")
    ap.add_argument("--frames", type=_frames_arg, default=None,
                    help="use frames A:B only (0-based, B excluded; a single trial only)")
    ap.add_argument("--markers", type=Path, default=None,
                    help="marker map (TOML: model label = [trial labels]) for labels the built-in aliases miss")
    ap.add_argument("--no-aliases", action="store_true",
                    help="do not rename common label spellings (R.ASIS, RASIS, ...) to the model's labels")
    ap.add_argument("--no-new-markers", action="store_true",
                    help="ignore trial markers the model does not know (default: place them on segments and fit)")
    ap.add_argument("--outlier-sigmas", type=_nonneg_float, default=None,
                    help="reject marker positions further than this many noise SDs from the fit (default 6; 0: off)")
    ap.add_argument("--config", type=Path, default=None, help="settings file (TOML; see docs/calibration.md)")
    ap.add_argument("--free", default=None,
                    help="comma-separated parameter groups to calibrate: scale,centre,axis,marker (default all)")
    ap.add_argument("--loss", choices=("linear", "huber", "cauchy"), default=None,
                    help="robust loss against marker outliers (default linear)")
    ap.add_argument("--noise-mm", type=_positive_float, default=None,
                    help="marker noise SD in mm, kept as given (default: learnt per marker from the residuals)")
    ap.add_argument("--no-learn-noise", action="store_true",
                    help="do not learn the markers' noise SDs from the residuals; use --noise-mm (default 1) for all")
    ap.add_argument("--no-seed", action="store_true", help="start from the base model, not from MTB joint centres")
    ap.add_argument("--lock", default=None, metavar="DOF[=DEG],...",
                    help="hold coordinates at a value (default 0 deg) in every frame, e.g. "
                         "subtalar_r,subtalar_l: what the marker set cannot resolve (as OpenSim's locked coordinates)")
    ap.add_argument("--hold-axes", default=None, metavar="DOF,...",
                    help="keep these hinge/universal axes at the base model's (their angles stay free)")
    ap.add_argument("--no-auto-hold", action="store_true",
                    help="calibrate the axes of coordinates the trial does not show moving too (by default they "
                         "are held at the base model's, and the summary says which)")
    ap.add_argument("--neutral", type=_int_at_least(1), default=None, metavar="K",
                    help="trial K (1 = the first) shows the subject standing in the model's neutral pose (a static "
                         "trial): segment frames are turned so that its joint angles are zero")
    ap.add_argument("--mass", type=_positive_float, default=None,
                    help="subject's body mass in kg: segment masses and inertias are the base model's scaled to "
                         "it (default: the base model's masses kept)")
    ap.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                    help="with an OpenSim MODEL.osim: an OpenSim MarkerSet file whose markers are added, replacing "
                         "those of the same name (as OpenSim's Scale tool does)")
    ap.add_argument("--overwrite", action="store_true", help="replace existing output files")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr")
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    first = next((a for a in argv if not a.startswith("-")), None)
    if first is not None and first not in COMMANDS and not any(a in ("-h", "--help") for a in argv[:1]):
        args = build_calibrate_parser().parse_args(argv)
        return _guard(cmd_calibrate, args)
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.command is None:
        ap.print_help()
        return 2
    from .io.osim_export import cmd_export_osim

    commands = {"simulate": cmd_simulate, "demo": cmd_demo, "inspect": cmd_inspect, "joints": cmd_joints,
                "export-osim": cmd_export_osim, "import-osim": cmd_import_osim}
    return _guard(commands[args.command], args)


def _guard(command, args: argparse.Namespace) -> int:
    """Run a command; one-line errors (exit 2) for bad input."""
    try:
        return command(args)
    except CalibrateError as e:
        print(f"calibrate: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calibrate: interrupted", file=sys.stderr)
        return 130


def _simulate(args: argparse.Namespace):
    from .model.model import load_model
    from .simulation.simulate import MOTIONS, simulate_realistic, write_simulation

    model = load_model(args.model or _default_model())
    if args.out.exists() and not args.out.is_dir():
        raise CalibrateError(f"{args.out}: exists and is not a directory; choose another --out")
    if not getattr(args, "overwrite", True):
        for name in ("trial.c3d", "truth.urdf", "truth_motion.csv", "truth_corruptions.csv"):
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
    except OSError as e:
        raise CalibrateError(f"{args.out}: cannot write ({e.strerror}); choose a writable --out") from None
    return model, sim, paths, time.perf_counter() - t0


def cmd_simulate(args: argparse.Namespace) -> int:
    model, sim, paths, dt = _simulate(args)
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
    for key in ("trial", "truth", "motion", "corruptions"):
        if key in paths:
            print(f"  {key:11s} {paths[key]}")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibration.pipeline import calibrate
    from .io.config import load_settings, settings_from_dict
    from .io.labels import load_marker_map
    from .io.trial import Trial, read_trial
    from .model.model import load_model
    from .problem.problem import Settings

    if len(args.inputs) < 2:
        raise CalibrateError("give one or more trials and then the base model: calibrate TRIAL [TRIAL ...] MODEL")
    *trial_paths, model_path = args.inputs
    if model_path.suffix.lower() in (".c3d", ".trc"):
        raise CalibrateError(f"{model_path}: the last argument must be the base model (.urdf), after the trials")
    if args.frames is not None and len(trial_paths) > 1:
        raise CalibrateError("--frames applies to a single trial; cut the trials first or give one trial")
    if args.motion is not None and len(trial_paths) > 1:
        raise CalibrateError("--motion names one file; with several trials each gets TRIAL_motion.csv beside it")
    stem = trial_paths[0].with_suffix("")
    out_urdf = args.output or stem.with_name(stem.name + ".urdf")
    out_motions = [args.motion] if args.motion else [t.with_suffix("").with_name(t.stem + "_motion.csv")
                                                      for t in trial_paths]
    out_report = args.report or stem.with_name(stem.name + "_report.json")
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
    if args.no_seed:
        flags["seed"] = False
    if args.no_new_markers:
        flags["new_markers"] = False
    if args.outlier_sigmas is not None:
        flags["outlier_sigmas"] = args.outlier_sigmas
    if args.lock is not None:
        flags["lock_deg"] = _lock_arg(args.lock)
    if args.hold_axes is not None:
        flags["hold_axes"] = [d.strip() for d in args.hold_axes.split(",") if d.strip()]
    if args.no_auto_hold:
        flags["auto_hold"] = False
    if flags:
        settings = settings_from_dict(flags, "command line", settings)
    outputs = [out_urdf, *out_motions, out_report]
    from_osim = model_path.suffix.lower() == ".osim"  # then also the subject .osim and .mot motions, OpenSim's names
    out_osim = out_urdf.with_suffix(".osim")
    out_mots = [m.with_suffix(".mot") for m in out_motions]
    if from_osim:
        outputs += [out_osim, *out_mots]
    # Check the destinations before any work, so a long run never ends in a refusal.
    check_targets(outputs, args.overwrite,
                  inputs={model_path: "that is the base model; refusing to overwrite it (choose another -o)"},
                  same="two outputs would be the same file (two trials with the same name?); use -o/--report "
                       "or rename the trials",
                  exists_hint="pass --overwrite to replace it or choose another name")
    say = (lambda msg: None) if args.quiet else _Timed()
    t0 = time.perf_counter()
    model = load_model(model_path, args.marker_set)
    if model_path.suffix.lower() == ".osim":  # the model's locked coordinates, unless --lock/--config set them
        from .io.osim import osim_info, with_locked

        settings = with_locked(model, settings)
        approx = osim_info(model).approximations  # type: ignore[union-attr]
        if approx and not args.quiet:
            _progress(f"note: {model_path.name}: {len(approx)} joints approximated (" + ", ".join(
                f"{a.joint} {a.max_marker_mm:.1f} mm" for a in approx) + f"); see 'calibrate inspect {model_path}'")
    marker_map = load_marker_map(args.markers) if args.markers else None
    trials = [read_trial(t) for t in trial_paths]
    if args.frames is not None:
        trial = trials[0]
        idx = range(trial.n_frames)[args.frames]
        if len(idx) == 0 or idx.step != 1:
            raise CalibrateError(f"--frames {args.frames.start}:{args.frames.stop}: selects no frames of "
                                 f"{trial_paths[0]} ({trial.n_frames} frames, 0-based)")
        trials[0] = Trial(trial.labels, trial.markers[idx.start:idx.stop], trial.rate,
                          trial.first_frame + idx.start, trial.source)
    load_s = time.perf_counter() - t0
    if args.neutral is not None and args.neutral > len(trials):
        raise CalibrateError(f"--neutral {args.neutral}: there are only {len(trials)} trials; give the number of the "
                             f"static trial (1 = the first)")
    cal = calibrate(model, trials, settings, marker_map=marker_map, aliases=not args.no_aliases, mass=args.mass,
                    neutral=None if args.neutral is None else args.neutral - 1, progress=say)
    if cal.ignored_labels:
        why = "are not markers of" if not settings.new_markers else "ride on no segment of"
        print(f"warning: {len(cal.ignored_labels)} trial labels {why} {model.path.name} and are ignored: "
              f"{', '.join(cal.ignored_labels)}", file=sys.stderr)
    cal = replace(cal, times={"load": load_s, **cal.times})
    cal = _write_timed(cal, urdf=out_urdf, motion=out_motions, report=out_report, overwrite=args.overwrite)
    if from_osim:
        from .io.osim_export import export_osim, write_mot

        subject = load_model(out_urdf)
        export_osim(subject, out_osim)
        for path, motion in zip(out_mots, cal.motions, strict=True):
            write_mot(path, subject, motion)
    print(cal.text())
    print("")
    print("wrote " + "\n      ".join(str(p) for p in outputs))
    if not cal.converged:
        print(f"warning: the solver did not converge ({cal.summary.termination}); the best result so far was "
              "written and is flagged in the report", file=sys.stderr)
        return 1
    return 0


def _write_timed(cal, **outputs):
    """cal.write(**outputs); returns cal with the time that took as times['write'] (what the summary shows)."""
    t0 = time.perf_counter()
    cal.write(**outputs)
    return replace(cal, times={**cal.times, "write": time.perf_counter() - t0})


class _Timed:
    """Progress on stderr with the elapsed time, shown once the run has taken a second (a long step's
    announcement at once; solver iterations at most twice a second)."""

    def __init__(self):
        self.t0 = time.perf_counter()
        self.last = 0.0

    def __call__(self, msg: Progress) -> None:
        now = time.perf_counter() - self.t0
        if (now >= 1.0 or msg.long) and (msg.iteration is None or now - self.last >= 0.5):
            self.last = now
            _progress(f"  [{now:6.2f} s] {msg}")


def cmd_demo(args: argparse.Namespace) -> int:
    from .calibration.evaluate import compare_to_truth
    from .calibration.pipeline import calibrate
    from .io.trial import read_trial

    model, sim, paths, dt = _simulate(args)
    trial = read_trial(paths["trial"])  # what a user would have: the C3D file
    kind = {"gait": "gait", "overhead": "overhead"}.get(args.motion or "", "squat")
    kind = "realistic " + kind if args.realistic else kind
    _progress(f"simulated a {kind} trial in {dt:.2f} s -> {args.out}/; calibrating {model.path.name} to it...")
    t0 = time.perf_counter()
    cal = calibrate(model, trial, progress=_Timed())
    t_cal = time.perf_counter() - t0
    cal = _write_timed(cal, urdf=args.out / "subject.urdf", motion=args.out / "subject_motion.csv",
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
    if path.suffix.lower() in (".urdf", ".osim"):
        from .model.model import load_model

        m = load_model(path, getattr(args, "marker_set", None))
        print(m.summary())
        print(f"  {'joint':16s} {'kind':9s} {'parent -> child':28s} centre (m, parent frame)")
        for j in m.joints:
            c = " ".join(f"{x:+.4f}" for x in j.centre)
            print(f"  {j.name:16s} {j.kind:9s} {j.parent + ' -> ' + j.child:28s} {c}")
        print("  markers per segment:")
        for s in m.segments:
            if s.markers:
                print(f"    {s.name:12s} {' '.join(s.markers)}")
        _print_osim(m)
        return 0
    from .io.trial import read_trial

    t = read_trial(path)
    gaps = np.isnan(t.markers[..., 0]).mean(axis=0)
    print(f"{path}: {t.n_frames} frames at {t.rate:g} Hz ({t.n_frames / t.rate:.2f} s), {t.n_markers} markers, "
          f"first frame {t.first_frame}")
    for lab, g in zip(t.labels, gaps, strict=True):
        print(f"  {lab:16s} gaps {100 * g:5.1f} %")
    return 0


def _print_osim(model) -> None:
    """What an OpenSim import approximated, locked and dropped (nothing for a model not from a .osim)."""
    from .io.osim import approximation_table, osim_info

    info = osim_info(model)
    if info is None:
        return
    print(f"  imported from OpenSim model {info.source}; approximated joints:")
    print(approximation_table(info))
    if info.locked:
        print(f"  locked coordinates (held in every frame): {', '.join(info.locked)}")
    if info.dropped:
        print(f"  coordinates that are not degrees of freedom here: {', '.join(info.dropped)}")


def cmd_import_osim(args: argparse.Namespace) -> int:
    """``calibrate import-osim MODEL.osim [--marker-set XML] [-o URDF]``."""
    from .io.text import atomic_write_text
    from .model.model import load_model

    src: Path = args.model
    out: Path = args.output or src.with_suffix(".urdf")
    if out.suffix.lower() != ".urdf":
        raise CalibrateError(f"{out}: the output is a URDF; give it a .urdf name")
    check_targets([out], args.overwrite, exists_hint="pass --overwrite to replace it or choose another -o")
    model = load_model(src, args.marker_set)
    try:
        atomic_write_text(out, model._text)
    except OSError as e:
        raise CalibrateError(f"{out}: cannot write ({e.strerror}); choose a writable place") from None
    print(model.summary())
    _print_osim(model)
    print(f"wrote {out}")
    return 0


def cmd_joints(args: argparse.Namespace) -> int:
    from .io.labels import load_marker_map, map_labels
    from .io.trial import read_trial
    from .model.model import load_model
    from .seed.joints import estimate_model_joints, write_centres_csv

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
    renamed = [m for m in mapping if m.how in ("map", "alias")]
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
    from .seed.association import associate_to_model

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


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
