"""All-or-nothing output files: every destination checked before any work, every file written under
its own name in a fresh folder beside its destination, all moved into place at the end.  A failure
leaves no output half-written and no destination changed.
"""

from __future__ import annotations

import os
import secrets
import shutil
import stat
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from ..errors import CalibrateError

Writer = Callable[[Path], None]  # writes one output file at the path it is given

OVERWRITE_HINT = "pass --overwrite (overwrite=True) or choose another name"


def check_targets(targets: Sequence[Path], overwrite: bool, *, inputs: Mapping[Path, str] | None = None,
                  same: str = "two outputs would be the same file; give them different names",
                  exists_hint: str = OVERWRITE_HINT) -> None:
    """Refuse (CalibrateError, one line) unless every target can be written: no two the same file,
    none an input (`inputs`: input path -> what to say, e.g. "that is the base model; refusing to
    overwrite it (choose another -o)"), none a directory, each in an existing writable folder, and
    none existing unless `overwrite`."""
    targets = [Path(t) for t in targets]
    if len({t.resolve() for t in targets}) < len(targets):
        raise CalibrateError(same)
    given = {Path(p).resolve(): why for p, why in (inputs or {}).items()}
    for path in targets:
        if path.resolve() in given:
            raise CalibrateError(f"{path}: {given[path.resolve()]}")
    for path in targets:
        if path.is_dir():
            raise CalibrateError(f"{path}: is a directory; give a file name")
        if not path.parent.is_dir():
            raise CalibrateError(f"{path}: directory '{path.parent}' does not exist; create it first")
        if path.exists() and not overwrite:
            raise CalibrateError(f"{path}: exists; {exists_hint}")
        if not os.access(path.parent, os.W_OK):
            raise CalibrateError(f"{path}: directory '{path.parent}' is not writable; choose another place")
        try:  # a file made and removed there: a read-only file system or /proc passes os.access (for root too)
            _staging_file(path).unlink()
        except OSError as e:
            raise CalibrateError(f"{path}: directory '{path.parent}' takes no new file ({e.strerror or e}); choose "
                                 "another place") from None


def write_all(writers: Mapping[Path, Writer], keep_names: bool = False) -> None:
    """Write every output (destination -> its writer, called in this order) or none, then rename all
    into place (place_all).  Each writer writes to a staging file beside its destination: a hidden
    temporary ('.NAME.*.part.SUFFIX'), or with `keep_names` a file of the destination's own name in a fresh
    hidden folder (for a format that quotes its file name, as a TRC header does).  The destinations
    should have passed check_targets."""
    staged: dict[Path, Path] = {}
    folders: list[Path] = []
    try:
        for target, write in writers.items():
            target = Path(target)
            if keep_names:
                folders.append(Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent)))
                staged[target] = folders[-1] / target.name
            else:
                staged[target] = _staging_file(target)
            write(staged[target])
            # A file it replaces keeps its permissions; a new one gets the user's (umask), not mkstemp's 0600.
            if target.exists():
                os.chmod(staged[target], stat.S_IMODE(target.stat().st_mode))
        place_all(staged)
    except OSError as e:  # a disk that fills, a folder removed meanwhile: one line, nothing written
        where = Path(e.filename).parent if e.filename else next(iter(writers), Path("."))
        raise CalibrateError(f"{where}: an output could not be written ({e.strerror or e}); nothing was written or "
                             "changed: free space or choose another place") from None
    finally:
        for tmp in staged.values():
            tmp.unlink(missing_ok=True)
        for folder in folders:
            shutil.rmtree(folder, ignore_errors=True)


def _staging_file(target: Path) -> Path:
    """A new, empty hidden file beside `target` ('.NAME.xxxxxxxx.part.SUFFIX': the destination's suffix
    last, in lower case, as a writer may insist on it; ezc3d appends .c3d otherwise), created as a new
    file is (mode 0666 less the umask: readable by whom the user's other files are)."""
    for _ in range(100):
        path = target.parent / f".{target.name}.{secrets.token_hex(4)}.part{target.suffix.lower()}"
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"{target}: no free name for its staging file in '{target.parent}'")


def place_all(staged: Mapping[Path, Path]) -> None:
    """Rename every staged file (destination -> staged file) onto its destination, all or none: a
    file a destination replaces is first moved aside, and if any rename fails, the destinations
    already placed are undone (removed, or their old file moved back) before the error goes on."""
    if len(staged) == 1:  # one file: a rename is atomic by itself, and leaves nothing to undo
        for target, tmp in staged.items():
            os.replace(tmp, target)
        return
    placed: list[tuple[Path, Path | None]] = []  # (target, where its previous file waits)
    try:
        for target, tmp in staged.items():
            aside = None
            if target.exists():
                fd, name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent)
                os.close(fd)
                aside = Path(name)
                os.replace(target, aside)
            placed.append((target, aside))
            os.replace(tmp, target)
    except BaseException:
        for target, aside in reversed(placed):
            if aside is not None:
                os.replace(aside, target)
            else:
                target.unlink(missing_ok=True)
        raise
    for _, aside in placed:
        if aside is not None:
            aside.unlink(missing_ok=True)


def put_text(staged: Path, text: str) -> None:
    """A writer's body for a text file: `text` as UTF-8 at the staged path write_all gives it (staged
    already: no second temporary file)."""
    staged.write_text(text, encoding="utf-8", newline="")


def write_text(path: Path, text: str) -> None:
    """Write `text` to `path` through a staged file renamed into place (write_all): a failure part-way
    leaves `path` as it was (absent or the old content), never half-written."""
    write_all({Path(path): lambda staged: put_text(staged, text)})
