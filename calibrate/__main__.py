"""``python -m calibrate``: the command line, as the ``calibrate`` program (calibrate.cli)."""

from .cli.main import run

run()
