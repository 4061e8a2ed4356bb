"""``calibrate report REPORT.json -o REPORT.html`` (the HTML report from the JSON alone) and
``calibrate view REPORT.json [--rrd FILE]`` (the 3-D view in rerun), and the progress bar of a
calibration on a terminal."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..calibration.records import Progress


def add_report_parsers(sub) -> None:
    """The 'report' and 'view' commands' parsers."""
    rp = sub.add_parser("report", help="the HTML report (one offline file) of a calibration's report JSON",
                        description="Write the HTML report of a calibration from its report JSON alone: notes, "
                                    "summary tables, marker errors (per marker, marker x time heat map with the "
                                    "rejected positions, residual curves), joint angles against the base model's "
                                    "limits, parameter changes with posterior SD and identifiability, segment "
                                    "lengths (docs/report.md).")
    rp.add_argument("report", type=Path, metavar="REPORT.json", help="the report JSON a calibration wrote")
    rp.add_argument("-o", "--output", type=Path, default=None, metavar="HTML",
                    help="the HTML file (default: REPORT's name + .html)")
    rp.add_argument("--overwrite", action="store_true", help="replace the output if it exists")
    vw = sub.add_parser("view", help="3-D view of a calibration in rerun (skeleton, markers, residuals)",
                        description="Show the subject of a calibration in the rerun viewer: joint centres, "
                                    "segments, hinge axes, measured and model markers over time with each marker's "
                                    "residual; from the report JSON and the files it names (subject URDF, motion "
                                    "CSVs, trials).  --rrd saves the recording instead of opening a viewer.")
    vw.add_argument("report", type=Path, metavar="REPORT.json", help="the report JSON a calibration wrote")
    vw.add_argument("--rrd", type=Path, default=None, metavar="FILE", help="save the recording to FILE (.rrd)")
    vw.add_argument("--overwrite", action="store_true", help="replace --rrd if it exists")


def cmd_report(args: argparse.Namespace) -> int:
    from ..calibration.html import read_report, write_report_html

    out = args.output or args.report.with_suffix(".html")
    rep = read_report(args.report)
    write_report_html(rep, out, overwrite=args.overwrite)
    print(f"wrote {out}")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from ..calibration.html import read_report
    from ..calibration.view import log_report, view_scene

    rep = read_report(args.report)
    scene = log_report(rep, args.report.parent)
    view_scene(scene, rrd=args.rrd, overwrite=args.overwrite)
    if args.rrd is not None:
        print(f"wrote {args.rrd}")
    return 0


class Bars:
    """Progress of a calibration as rich progress bars on stderr (a terminal): one line per stage,
    a bar over the solver's iterations (out of `max_iterations`).  Use as a context manager."""

    def __init__(self, max_iterations: int, stream=None):
        from rich.console import Console
        from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        self.max_iterations = max_iterations
        self.bars = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(),
                             TextColumn("{task.completed}/{task.total}"), TimeElapsedColumn(),
                             console=Console(file=sys.stderr if stream is None else stream), transient=False)
        self.task = None
        self.stage = None

    def __enter__(self) -> Bars:
        self.bars.start()
        return self

    def __exit__(self, *exc) -> None:
        self._finish()
        self.bars.stop()

    def _finish(self) -> None:
        """Close the current line: a solve's bar ends at the iterations it took."""
        if self.task is not None:
            done = max(1, int(self.bars.tasks[-1].completed)) if self.stage and self.stage[1] else 1
            self.bars.update(self.task, total=done, completed=done)

    def __call__(self, msg: Progress) -> None:
        key = (msg.stage, msg.iteration is not None)
        if key != self.stage:
            self._finish()
            self.stage = key
            total = self.max_iterations if msg.iteration is not None else 1
            self.task = self.bars.add_task(str(msg)[:70], total=total)
        if msg.iteration is not None:
            self.bars.update(self.task, completed=min(msg.iteration, self.max_iterations),
                             description=str(msg)[:70])
        else:
            self.bars.update(self.task, description=str(msg)[:70])


def progress_for(quiet: bool, max_iterations: int, plain, stream=None):
    """The progress of a calibration: nothing (`quiet`), rich bars when `stream` (stderr) is a terminal
    and rich is installed, else `plain()` (the one-line progress)."""
    from contextlib import nullcontext

    stream = sys.stderr if stream is None else stream
    if quiet:
        return nullcontext(lambda msg: None)
    if stream.isatty():
        try:
            return Bars(max_iterations, stream)
        except ImportError:
            pass
    return nullcontext(plain())
