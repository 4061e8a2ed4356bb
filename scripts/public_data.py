#!/usr/bin/env python
"""The public sweep's trial files (scripts/bench_sweep.py) taken out of git repositories into one flat folder.

    python scripts/public_data.py --into DIR GITDIR:PREFIX[:FOLDER] [GITDIR:PREFIX[:FOLDER] ...]

Each C3D or TRC file under FOLDER (default: the whole tree) of the repository's HEAD is written to DIR as
``PREFIX__`` followed by its path below FOLDER with ``/`` as ``__``: BTKData's ``Input/C3DSamples/PiG/PiG_Calibration-
FlatFoot-Full.c3d`` with ``btk`` and ``Input/C3DSamples`` becomes ``btk__PiG__PiG_Calibration-FlatFoot-Full.c3d``,
the names docs/benchmarks.md's sweeps give.  GITDIR is a repository's git directory (a bare mirror, or a clone's
``.git``).  A file the repository lists but whose content it lacks (a shallow snapshot leaves out its largest
files) is written empty, as a sweep met it (bench_sweep records its one-line refusal).  The sweeps' sources:

    BTKData (github.com/Biomechanical-ToolKit/BTKData)          GITDIR:btk:Input/C3DSamples  (69 files)
    kineticstoolkit (github.com/felixchenier/kineticstoolkit)   GITDIR:ktk                   (11, all under data/)

Nothing is downloaded here: clone or mirror the repositories first.  Existing files in DIR are left as they are
(``--overwrite`` replaces them).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

SUFFIXES = (".c3d", ".trc")


def source(spec: str) -> tuple[Path, str, str]:
    """(git directory, prefix, folder) of a GITDIR:PREFIX[:FOLDER] argument."""
    parts = spec.split(":")
    if len(parts) not in (2, 3) or not all(parts[:2]):
        raise ValueError(f"{spec}: give GITDIR:PREFIX or GITDIR:PREFIX:FOLDER")
    return Path(parts[0]), parts[1], (parts[2] if len(parts) == 3 else "").strip("/")


def _git(gitdir: Path, *args: str) -> subprocess.CompletedProcess:
    """`git ARGS` on the repository whose git directory is `gitdir` (output captured as bytes, never raising)."""
    return subprocess.run(["git", f"--git-dir={gitdir}", *args], capture_output=True)


def trial_paths(gitdir: Path, folder: str) -> list[str]:
    """The C3D and TRC paths (any case of suffix) under `folder` of the repository's HEAD, sorted."""
    out = _git(gitdir, "ls-tree", "-r", "--name-only", "HEAD", *([folder] if folder else [])).stdout.decode()
    return sorted(p for p in out.splitlines() if p.lower().endswith(SUFFIXES))


def flat_name(path: str, prefix: str, folder: str) -> str:
    """`path` below `folder`, its separators as '__', after `prefix`."""
    below = path[len(folder) + 1:] if folder else path
    return "__".join([prefix, *below.split("/")])


def extract(gitdir: Path, prefix: str, folder: str, into: Path, overwrite: bool = False) -> tuple[int, int]:
    """Every trial file of one repository written into `into`; (written, of them empty: content absent)."""
    written = empty = 0
    for path in trial_paths(gitdir, folder):
        dest = into / flat_name(path, prefix, folder)
        if dest.exists() and not overwrite:
            continue
        blob = _git(gitdir, "show", f"HEAD:{path}")
        data = blob.stdout if blob.returncode == 0 else b""
        dest.write_bytes(data)
        written += 1
        empty += not data
    return written, empty


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sources", nargs="+", metavar="GITDIR:PREFIX[:FOLDER]")
    ap.add_argument("--into", type=Path, required=True, help="the flat folder the files go to (made if missing)")
    ap.add_argument("--overwrite", action="store_true", help="replace files already there")
    a = ap.parse_args(argv)
    try:
        specs = [source(s) for s in a.sources]
    except ValueError as e:
        print(f"public_data: {e}", file=sys.stderr)
        return 2
    for gitdir, _, _ in specs:
        if _git(gitdir, "rev-parse", "HEAD").returncode:
            print(f"public_data: {gitdir}: not a git directory with a HEAD; give a mirror or a clone's .git",
                  file=sys.stderr)
            return 2
    a.into.mkdir(parents=True, exist_ok=True)
    for gitdir, prefix, folder in specs:
        n, empty = extract(gitdir, prefix, folder, a.into, a.overwrite)
        print(f"{gitdir}: {n} files written to {a.into} ({empty} empty: not in the snapshot)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
