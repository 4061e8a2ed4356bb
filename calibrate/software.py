"""The versions a result depends on: calibrate's, Python's and those of the libraries that hold the model, build and
solve the problem and read and write the files, which a lab records beside a result to reproduce it
(``calibrate --version``; the report's "software")."""

from __future__ import annotations

import functools
import platform
from importlib import metadata

#: The libraries a calibration's numbers pass through: (the name shown, its distributions on PyPI or conda-forge).
LIBRARIES = (("casadi", ("casadi",)), ("pinocchio", ("pin", "pinocchio")), ("ezc3d", ("ezc3d",)),
             ("yourdfpy", ("yourdfpy",)), ("numpy", ("numpy",)), ("scipy", ("scipy",)))


@functools.cache
def _versions() -> tuple[tuple[str, str], ...]:
    """software_versions' pairs, read once a process (the installed distributions' metadata: 4-6 ms a read, and
    `calibrate ik` writes a report per trial)."""
    from . import __version__

    out = {"calibrate": __version__, "python": platform.python_version()}
    for name, dists in LIBRARIES:
        out[name] = "not installed"
        for dist in dists:
            try:
                out[name] = metadata.version(dist)
                break
            except metadata.PackageNotFoundError:
                continue
    return tuple(out.items())


def software_versions() -> dict[str, str]:
    """{"calibrate": ..., "python": ..., then each of LIBRARIES: its installed version, or "not installed"}."""
    return dict(_versions())


def version_line() -> str:
    """`calibrate --version`'s line: 'calibrate 0.1.0 (Python 3.11.7; casadi 3.8.2, pinocchio 4.1.0, ...)'."""
    v = software_versions()
    libs = ", ".join(f"{name} {v[name]}" for name, _ in LIBRARIES)
    return f"calibrate {v['calibrate']} (Python {v['python']}; {libs})"
