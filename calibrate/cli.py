"""Command line: ``calibrate simulate``, ``calibrate demo``, ``calibrate inspect``, ``calibrate joints``.

A thin layer over the Python API.  Bad input gives one line on stderr
(``calibrate: error: ...``) and exit status 2; nothing half-written.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from .errors import CalibrateError

DEFAULT_MODEL = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got '{text}'") from None
    if v < 2:
        raise argparse.ArgumentTypeError(f"need at least 2, got {v}")
    return v


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


def _default_model() -> Path:
    """models/human.urdf of the source tree; in an installed package (no source tree) the same
    model is generated from calibrate.human into the temporary directory."""
    if DEFAULT_MODEL.exists():
        return DEFAULT_MODEL
    import tempfile

    from .human import build_human_urdf

    path = Path(tempfile.gettempdir()) / "calibrate-human.urdf"
    text = build_human_urdf()
    if not path.exists() or path.read_text() != text:
        path.write_text(text)
    return path


def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


class _FrameProgress:
    """Prints 'label: done/total frames' to stderr at most once a second, after the first second."""

    def __init__(self, label: str):
        self.label, self.t0, self.last = label, time.perf_counter(), 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter() - self.t0
        if now > 1.0 and now - self.last >= 1.0:
            self.last = now
            _progress(f"  {self.label}: {done}/{total} frames ({now:.0f} s)")


def _add_sim_args(p: argparse.ArgumentParser, frames: int) -> None:
    p.add_argument("--frames", type=_positive_int, default=frames, help=f"number of frames (default {frames})")
    p.add_argument("--rate", type=_positive_float, default=100.0, help="frame rate in Hz (default 100)")
    p.add_argument("--noise-mm", type=_nonneg_float, default=1.0, help="marker noise SD in mm (default 1)")
    p.add_argument("--gaps", action="store_true", help="add realistic occlusion gaps")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--model", type=Path, default=None, help="base model URDF (default: models/human.urdf)")


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors: 'calibrate simulate: error: ...; see --help', exit 2."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(
        prog="calibrate",
        description="Subject-specific human models from motion-capture trials.",
    )
    sub = ap.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sim = sub.add_parser("simulate", help="write a synthetic squat trial with its truth",
                         description="Simulate squats of a random synthetic subject derived from a base model; "
                                     "writes OUT/trial.c3d, OUT/truth.urdf and OUT/truth_motion.csv.")
    sim.add_argument("--out", type=Path, required=True, help="output directory (created if missing)")
    sim.add_argument("--overwrite", action="store_true", help="replace trial.c3d/truth.urdf/truth_motion.csv in OUT")
    _add_sim_args(sim, 1000)
    demo = sub.add_parser("demo", help="simulate a squat trial into ./calibrate-demo and summarise it",
                          description="Simulate a squat trial into ./calibrate-demo/ (its files are replaced on "
                                      "every run) and report how well the base model's kinematics reproduce it.")
    demo.add_argument("--out", type=Path, default=Path("calibrate-demo"), help="output directory")
    _add_sim_args(demo, 1000)
    ins = sub.add_parser("inspect", help="describe a model (.urdf) or a trial (.c3d/.trc)")
    ins.add_argument("file", type=Path, help="a .urdf, .c3d or .trc file")
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
    jo.add_argument("--mode", choices=("framework", "jmv"), default="framework",
                    help="'framework' (default) or 'jmv': every joint by per-frame JMV only (slow baseline)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.command is None:
        ap.print_help()
        return 2
    try:
        commands = {"simulate": cmd_simulate, "demo": cmd_demo, "inspect": cmd_inspect, "joints": cmd_joints}
        return commands[args.command](args)
    except CalibrateError as e:
        print(f"calibrate: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calibrate: interrupted", file=sys.stderr)
        return 130


def _simulate(args: argparse.Namespace):
    from .model import load_model
    from .simulate import simulate_squats, write_simulation

    model = load_model(args.model or _default_model())
    if args.out.exists() and not args.out.is_dir():
        raise CalibrateError(f"{args.out}: exists and is not a directory; choose another --out")
    if not getattr(args, "overwrite", True):
        for name in ("trial.c3d", "truth.urdf", "truth_motion.csv"):
            if (args.out / name).exists():
                raise CalibrateError(
                    f"{args.out / name}: exists; pass --overwrite to replace it or choose another --out"
                )
    t0 = time.perf_counter()
    sim = simulate_squats(model, frames=args.frames, rate=args.rate, noise_mm=args.noise_mm,
                          gaps=args.gaps, seed=args.seed)
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
    for key in ("trial", "truth", "motion"):
        print(f"  {key:7s} {paths[key]}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from .ik import inverse_kinematics
    from .kinematics import build_kinematics
    from .trial import read_trial

    model, sim, paths, dt = _simulate(args)
    trial = read_trial(paths["trial"])  # what a user would have: the C3D file
    _progress(f"simulated a squat trial in {dt:.2f} s -> {args.out}/")
    kin = build_kinematics(model)
    t0 = time.perf_counter()
    _progress("fitting the base model (inverse kinematics, frame by frame)...")
    base = inverse_kinematics(kin, trial, model.parameters(), progress=_FrameProgress("base model"))
    t_base = time.perf_counter() - t0
    _progress("fitting the true subject model (the noise floor)...")
    true = inverse_kinematics(kin, trial, sim.truth, progress=_FrameProgress("true model"))
    gaps = float(np.isnan(trial.markers[..., 0]).mean())
    ang = np.degrees(np.angle(np.exp(1j * (base.motion.angles - sim.motion.angles))))
    rms_ang = np.sqrt(np.mean(ang**2, axis=0))
    worst = np.argsort(rms_ang)[::-1][:3]
    print(f"calibrate demo: {model.summary()}")
    print(f"trial   {paths['trial']}: {trial.n_frames} frames at {trial.rate:g} Hz, {trial.n_markers} markers, "
          f"noise {args.noise_mm:g} mm, gaps {100 * gaps:.1f} %")
    print(f"truth   {paths['truth']}, {paths['motion']}")
    print("")
    print("how well each model's kinematics reproduce the trial (frame-wise inverse kinematics):")
    print(f"  {'model':28s} {'marker RMS':>11s} {'max':>9s} {'time':>8s}")
    print(f"  {'base (uncalibrated)':28s} {1e3 * base.rms:8.2f} mm {1e3 * base.max_error:6.1f} mm {t_base:6.2f} s")
    print(f"  {'true subject (noise floor)':28s} {1e3 * true.rms:8.2f} mm {1e3 * true.max_error:6.1f} mm")
    print(f"  joint angles of the base model vs truth: RMS over DoFs {np.sqrt(np.mean(rms_ang**2)):.1f} deg; "
          f"worst " + ", ".join(f"{model.dof_names[i]} {rms_ang[i]:.1f} deg" for i in worst))
    print("")
    print("The gap between the two rows is what calibrating the model to this subject removes.")
    return 0


def cmd_inspect(args: argparse.Namespace) -> int:
    path: Path = args.file
    if path.suffix.lower() == ".urdf":
        from .model import load_model

        m = load_model(path)
        print(m.summary())
        print(f"  {'joint':16s} {'kind':9s} {'parent -> child':28s} centre (m, parent frame)")
        for j in m.joints:
            c = " ".join(f"{x:+.4f}" for x in j.centre)
            print(f"  {j.name:16s} {j.kind:9s} {j.parent + ' -> ' + j.child:28s} {c}")
        print("  markers per segment:")
        for s in m.segments:
            if s.markers:
                print(f"    {s.name:12s} {' '.join(s.markers)}")
        return 0
    from .trial import read_trial

    t = read_trial(path)
    gaps = np.isnan(t.markers[..., 0]).mean(axis=0)
    print(f"{path}: {t.n_frames} frames at {t.rate:g} Hz ({t.n_frames / t.rate:.2f} s), {t.n_markers} markers, "
          f"first frame {t.first_frame}")
    for lab, g in zip(t.labels, gaps, strict=True):
        print(f"  {lab:16s} gaps {100 * g:5.1f} %")
    return 0


def cmd_joints(args: argparse.Namespace) -> int:
    from .joints import estimate_model_joints, write_centres_csv
    from .model import load_model
    from .trial import read_trial

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
    from .association import associate_to_model

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
