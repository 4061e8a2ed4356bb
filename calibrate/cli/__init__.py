"""The command line: ``calibrate TRIAL [TRIAL ...] MODEL`` (calibrate a subject), ``calibrate simulate``,
``calibrate demo``, ``calibrate inspect``, ``calibrate joints``, ``calibrate export-osim``,
``calibrate import-osim``: parsing in calibrate.cli.main, argument types in calibrate.cli.args, the
commands in calibrate.cli.commands (a thin layer over the Python API)."""

from .main import build_calibrate_parser, build_parser, main

__all__ = ["build_calibrate_parser", "build_parser", "main"]
