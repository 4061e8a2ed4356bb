"""``python -m calibrate.cli``: the command line."""

from .main import run

run()
