"""Bad input, fuzzed: every reader of a user's file given N randomly damaged copies of a real one.

What must hold for each copy: the reader returns, or raises calibrate's one-line error (CalibrateError, no newline);
never another Python exception, never a message on the terminal from a C or C++ parser underneath (urdfdom), never a
crash of the interpreter or a runaway allocation (C3D copies are read in a child process under a 3 GB address-space
cap and a time limit).  Kinds:

- c3d: 1-3 random bytes of the header and parameter section of a C3D written by calibrate.io.c3d.write_c3d
  (gait2392's static, 20 frames) with two analog channels' parameters added;
- trc: lines of gait2392's walk deleted, repeated, cut, a character or a field changed, the header's numbers changed;
- qtm-tsv, motive-csv: the same damage to gait2392's walk written as Qualisys QTM's and OptiTrack Motive's exports
  (tests/test_tables.py's writers, Motive's with a rigid body, marker constraints and an unlabelled marker);
- osim, marker-set, ik-setup, scale-setup: an element of gait2392's files (Rajagopal2016.osim with --osim rajagopal)
  removed, emptied, renamed, duplicated, cut, or its number text garbled;
- urdf: an attribute of models/human.urdf garbled or an element removed;
- settings, marker-map: a line of docs/calibration.md's settings example (every setting) or of a marker map deleted,
  repeated, its value or key garbled;
- report: 1-2 entries of the report JSON of a calibration of pig_walk's walk deleted or set to another type, read
  by `calibrate ik WALK SUBJECT --report REPORT` (exit 0 or 2 with one line).

    python scripts/fuzz_inputs.py --kinds c3d,urdf --n 300 --seed 0 [--json out.json]

Findings are printed as the first copy of each kind of failure (its file kept under --keep DIR).  Data: ../shared
(as bench_osim).  No timings: this is a check, not a benchmark."""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import subprocess
import sys
import tempfile
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
GAIT = REAL / "gait2392"
KINDS = ("c3d", "trc", "qtm-tsv", "motive-csv", "osim", "marker-set", "ik-setup", "scale-setup", "urdf", "settings",
         "marker-map", "report")
WORDS = ["", "x", "nan", "inf", "1e999", "-1", "0", "1 2", "true", "false", "1,5", "1_0", "-0", "Unassigned"]

C3D_CHILD = r"""
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
from calibrate.errors import CalibrateError
from calibrate.io.c3d import read_c3d
try:
    read_c3d(sys.argv[1]); print("OK")
except CalibrateError as e:
    print("ERR" if "\n" not in str(e) else "MULTILINE " + str(e)[:150])
except BaseException as e:
    print("EXC " + type(e).__name__ + ": " + str(e)[:150])
"""


def _element_mutant(src: str, rng: random.Random) -> str:
    """`src` (XML) with 1-2 of its leaf elements removed, emptied, garbled, renamed, cut or duplicated."""
    leaves = [m for m in re.finditer(r"<(\w+)((?:\s[^>]*)?)>([^<]*)</\1>", src)]
    edits = []
    for _ in range(rng.choice([1, 1, 2])):
        m = rng.choice(leaves)
        tag, attrs, text, el = m.group(1), m.group(2), m.group(3), m.group(0)
        op = rng.randrange(7)
        if op == 0:
            new = ""
        elif op == 1:
            new = f"<{tag}{attrs}>{rng.choice(WORDS)}</{tag}>"
        elif op == 2 and text.split():
            parts = text.split()
            parts[rng.randrange(len(parts))] = rng.choice(WORDS)
            new = f"<{tag}{attrs}>{' '.join(parts)}</{tag}>"
        elif op == 3:
            new = f"<{tag}X{attrs}>{text}</{tag}X>"
        elif op == 4:
            old = re.search(r'name="([^"]*)"', el)
            name = rng.choice(["", "ground", "pelvis", (old.group(1) if old else "") + "2"])
            new = el if old is None else el[: old.start(1)] + name + el[old.end(1):]
        elif op == 5:
            new = el[: rng.randrange(len(el))]
        else:
            new = el + el
        edits.append((m.start(), m.end(), new))
    return _apply(src, edits)


def _apply(src: str, edits: list[tuple[int, int, str]]) -> str:
    """`src` with the (start, end, text) edits made, overlapping ones skipped."""
    last = len(src) + 1
    for a, b, new in sorted(edits, reverse=True):
        if b <= last:
            src, last = src[:a] + new + src[b:], a
    return src


def _urdf_mutant(src: str, rng: random.Random) -> str:
    """`src` (a URDF) with 1-2 attributes garbled or self-closing elements removed."""
    attrs = [m.span(2) for m in re.finditer(r'(\w+)="([^"]*)"', src)]
    shut = [m.span() for m in re.finditer(r"<[^<>]*/>", src)]
    edits = []
    for _ in range(rng.choice([1, 1, 2])):
        if rng.random() < 0.8:
            a, b = rng.choice(attrs)
            parts = src[a:b].split()
            op = rng.randrange(4)
            if op == 0:
                new = rng.choice(WORDS + ["0 0 0 0"])
            elif op == 1 and parts:
                parts[rng.randrange(len(parts))] = rng.choice(WORDS)
                new = " ".join(parts)
            elif op == 2:
                new = src[a:b] + "_2"
            else:
                new = rng.choice(["pelvis", "femur_l", "knee_l", "revolute", "continuous", "prismatic", "fixed"])
        else:
            (a, b), new = rng.choice(shut), ""
        edits.append((a, b, new))
    return _apply(src, edits)


def _trc_mutant(lines: list[str], rng: random.Random, sep: str = "\t") -> str:
    """The TRC `lines` with 1-3 lines deleted, repeated, cut, a character or field changed, or the header's numbers
    (`sep`: the fields' separator)."""
    lines = list(lines)
    for _ in range(rng.choice([1, 1, 2, 3])):
        if not lines:
            break
        i = rng.randrange(min(len(lines), 12)) if rng.random() < 0.6 else rng.randrange(len(lines))
        op = rng.randrange(7)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[rng.randrange(len(lines))])
        elif op == 2 and lines[i]:
            j = rng.randrange(len(lines[i]))
            lines[i] = lines[i][:j] + rng.choice("\t ,.-0123456789eE+nN\x00\r#x\u00e9") + lines[i][j + 1:]
        elif op == 3:
            lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)] + ("\n" if rng.random() < 0.5 else "")
        elif op == 4:
            f = lines[i].split(sep)
            f[rng.randrange(len(f))] = rng.choice(WORDS)
            lines[i] = sep.join(f)
        elif op == 5:
            lines = lines[: i + 1]
        elif len(lines) > 2:
            f = lines[2].split(sep)
            f[rng.randrange(len(f))] = rng.choice(["0", "-5", "100000", "x", "", "0.0", "m", "inches"])
            lines[2] = sep.join(f)
    return "".join(lines)


def _toml_mutant(lines: list[str], rng: random.Random) -> str:
    """The TOML `lines` with 1-2 lines deleted, repeated, or a value or key garbled."""
    lines = list(lines)
    for _ in range(rng.choice([1, 1, 2])):
        i = rng.randrange(len(lines))
        key, eq, value = lines[i].partition("=")
        op = rng.randrange(5)
        if op == 0:
            del lines[i]
        elif op == 1:
            lines.insert(i, lines[i])
        elif op == 2 and eq:
            lines[i] = key + "= " + rng.choice(['"x"', "-1", "0", "1e999", "nan", "inf", "true", "[]", '["a", 1]', "{}",
                                                '""', "[[1]]", "1.5", '"subtalar_l"']) + "\n"
        elif op == 3 and eq:
            lines[i] = rng.choice(["x", "lock", "priors", "noise", key.strip() + "2", '"a b"']) + " =" + value
        else:
            lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)] + "\n"
    return "".join(lines)


MARKER_MAP = """# model label = the trial's labels
RASI = ["R.ASIS", "Sub01:RASI"]
LASI = ["L.ASIS"]
RPSI = "R.PSIS"
LKNE = ["L.Knee", "L.Knee.Lat"]
[segments]
femur_l = ["L.Post.Fem.", "L.Ant.Fem."]
tibia_l = "L.Ant.Tib."
"""


def _json_mutant(src: str, rng: random.Random) -> str:
    """The JSON `src` with 1-2 entries (anywhere in it, the first 3 of a list) deleted or set to another type."""
    data = json.loads(src)

    def paths(o: object, pre: tuple = ()) -> list[tuple]:
        inner = o.items() if isinstance(o, dict) else enumerate(o[:3]) if isinstance(o, list) else []
        return [p for k, v in inner for p in ((*pre, k), *paths(v, (*pre, k)))]

    every = paths(data)
    for _ in range(rng.choice([1, 2])):
        *where, last = rng.choice(every)
        try:
            o = data
            for k in where:
                o = o[k]
            if rng.random() < 0.4:
                del o[last]
            else:
                o[last] = rng.choice([None, "x", -1, 1e308, [], {}, [1, "a"], True, "nan"])
        except (KeyError, IndexError, TypeError):
            pass
    return json.dumps(data)


def _c3d_base() -> bytes:
    """A C3D written by calibrate (gait2392's static, 20 frames) with two analog channels' parameters added."""
    import ezc3d

    from calibrate.io.c3d import write_c3d
    from calibrate.io.read import read_trial

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "base.c3d"
        write_c3d(path, read_trial(GAIT / "subject01_static.trc").frames(0, 20))
        c = ezc3d.c3d(str(path))
        c.add_parameter("ANALOG", "OFFSET", [0, 0])
        c.add_parameter("EXPERIMENT", "SESSION", [1, 2], description="a session number")
        c.write(str(path))
        return path.read_bytes()


def _c3d_mutant(base: bytes, rng: random.Random) -> bytes:
    """`base` with 1-3 random bytes of its header or parameter section changed."""
    data = bytearray(base)
    end = 512 * (int.from_bytes(base[16:18], "little") - 1)  # the data section's first byte
    for _ in range(rng.choice([1, 1, 2, 3])):
        data[rng.randrange(0, end) if rng.random() < 0.85 else rng.randrange(0, 24)] = rng.randrange(256)
    return bytes(data)


def _reader(kind: str, osim: str, scratch: Path) -> tuple[Callable[[Path], object], str, str]:
    """(read a file of `kind`, the source text to damage, the copies' suffix); `scratch`: a folder for its files."""
    from calibrate.io import osim_setup as setup
    from calibrate.io.read import read_trial
    from calibrate.model.model import load_model
    from calibrate.problem.settings import Settings

    model_path = REAL / "rajagopal_walk" / "Rajagopal2016.osim" if osim == "rajagopal" else GAIT / "gait2392.osim"
    marker_set = None if osim == "rajagopal" else GAIT / "gait2392_Scale_MarkerSet.xml"
    if kind == "trc":
        return read_trial, (GAIT / "subject01_walk1.trc").read_text(), ".trc"
    if kind in ("qtm-tsv", "motive-csv"):
        sys.path.insert(0, str(ROOT / "tests"))
        from test_tables import motive_text, qtm_text

        walk = read_trial(GAIT / "subject01_walk1.trc")
        if kind == "qtm-tsv":
            return read_trial, qtm_text(walk), ".tsv"
        return read_trial, motive_text(walk, unlabelled=walk.markers[:, 0] + 0.3), ".csv"
    if kind == "osim":
        return (lambda p: load_model(p, marker_set)), model_path.read_text(), ".osim"
    if kind == "marker-set":
        return (lambda p: load_model(GAIT / "gait2392.osim", p)), (GAIT / "gait2392_Scale_MarkerSet.xml").read_text(), \
            ".xml"
    if kind == "urdf":
        return load_model, (ROOT / "models" / "human.urdf").read_text(), ".urdf"
    if kind == "settings":
        from calibrate.io.config import load_settings

        docs = (ROOT / "docs" / "calibration.md").read_text()
        example = next(b for b in re.findall(r"```toml\n(.*?)```", docs, flags=re.S) if "[marker_noise_mm]" in b)
        return load_settings, example, ".toml"
    if kind == "marker-map":
        from calibrate.io.labels import load_marker_map

        return load_marker_map, MARKER_MAP, ".toml"
    if kind == "report":
        import contextlib
        import io

        from calibrate.cli.main import main as cli

        work = scratch / "calibration"
        work.mkdir()
        walk = REAL / "pig_walk" / "walk.c3d"
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            cli([str(walk), str(ROOT / "models" / "human.urdf"), "-o", str(work / "subject.urdf"), "-q"])

        def ik(p: Path) -> None:
            err = io.StringIO()
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
                code = cli(["ik", str(walk), str(work / "subject.urdf"), "--report", str(p), "-o", str(work),
                            "--overwrite", "-q"])
            if code == 2 and err.getvalue().count("\n") == 1:
                from calibrate.errors import CalibrateError

                raise CalibrateError(err.getvalue().strip())
            if code != 0:
                raise RuntimeError(f"exit {code}: {err.getvalue()[:150]}")
        return ik, (work / "walk_report.json").read_text(), ".json"
    model = load_model(GAIT / "gait2392.osim", GAIT / "gait2392_Scale_MarkerSet.xml")
    trials = [read_trial(GAIT / "subject01_static.trc"), read_trial(GAIT / "subject01_walk1.trc")]
    if kind == "ik-setup":
        def ik(p: Path) -> None:
            setup.ik_setup_locks(p, model)
            setup.ik_setup_notes(p, model)
            setup.ik_setup_weights(p)
            setup.ik_setup_range(p)
            setup.with_ik_setup(model, Settings(), p)
            setup.setup_outputs(None, p)
            setup.ik_setup_inputs(p)
            setup.describe_setup(p)
        return ik, (GAIT / "subject01_Setup_IK.xml").read_text(), ".xml"

    def scale(p: Path) -> None:
        setup.scale_setup(p)
        setup.setup_pose(p, model, trials, ["subject01_static.trc", "subject01_walk1.trc"])
        setup.setup_outputs(p, None)
        setup.scale_setup_inputs(p)
        setup.describe_setup(p)
    return scale, (GAIT / "subject01_Setup_Scale.xml").read_text(), ".xml"


def _read_quietly(read: Callable[[Path], object], path: Path) -> tuple[str, str]:
    """(outcome, what the file descriptor 2 received) of read(path): 'OK', 'ERR', 'MULTILINE ...' or 'EXC ...'."""
    from calibrate.errors import CalibrateError

    with tempfile.TemporaryFile() as cap:
        saved = os.dup(2)
        os.dup2(cap.fileno(), 2)
        try:
            try:
                read(path)
                outcome = "OK"
            except CalibrateError as e:
                outcome = "ERR" if "\n" not in str(e) else "MULTILINE " + str(e)[:150]
            except Exception as e:  # noqa: BLE001 - what this script looks for
                where = traceback.extract_tb(e.__traceback__)[-1]
                outcome = f"EXC {type(e).__name__} at {Path(where.filename).name}:{where.lineno}: {str(e)[:120]}"
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        cap.seek(0)
        return outcome, cap.read().decode(errors="replace").strip()


def fuzz(kind: str, n: int, seed: int, keep: Path, osim: str) -> dict:
    """`n` damaged copies of `kind`'s file read; counts and the first copy of each finding."""
    rng = random.Random(seed)
    keep.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="calibrate-fuzz-") as scratch:
        return _fuzz(kind, n, rng, keep, osim, Path(scratch), seed)


def _fuzz(kind: str, n: int, rng: random.Random, keep: Path, osim: str, where: Path, seed: int) -> dict:
    """fuzz's work, its copies written in `where` (removed afterwards)."""
    counts: dict[str, int] = {}
    findings: dict[str, str] = {}
    if kind == "c3d":
        base = _c3d_base()
    else:
        read, src, suffix = _reader(kind, osim, where)
        # setups name their marker set and trials relative to themselves: the copies are written beside them
        if kind in ("ik-setup", "scale-setup"):
            for f in GAIT.iterdir():
                (where / f.name).write_bytes(f.read_bytes())
        lines = src.splitlines(keepends=True)
    for k in range(n):
        if kind == "c3d":
            path = keep / f"{kind}-{seed}-{k}.c3d"
            path.write_bytes(_c3d_mutant(base, rng))
            try:
                run = subprocess.run([sys.executable, "-c", C3D_CHILD, str(path)], capture_output=True, text=True,
                                     timeout=60)
                out = run.stdout.strip().splitlines()
                outcome = out[-1] if out else f"CRASH rc {run.returncode}: {run.stderr.strip()[-120:]}"
            except subprocess.TimeoutExpired:
                outcome = "TIMEOUT"
            noise = ""
        else:
            text = (_trc_mutant(lines, rng) if kind in ("trc", "qtm-tsv")
                    else _trc_mutant(lines, rng, ",") if kind == "motive-csv"
                    else _urdf_mutant(src, rng) if kind == "urdf"
                    else _toml_mutant(lines, rng) if kind in ("settings", "marker-map")
                    else _json_mutant(src, rng) if kind == "report" else _element_mutant(src, rng))
            path = where / f"{kind}-{seed}-{k}{suffix}"
            path.write_text(text, encoding="utf-8", errors="surrogateescape")
            outcome, noise = _read_quietly(read, path)
        label = outcome.split(" ")[0]
        if noise:
            label, outcome = "NOISE", f"{outcome}; on the terminal: {noise.splitlines()[0][:120]}"
        counts[label] = counts.get(label, 0) + 1
        if label in ("OK", "ERR"):
            path.unlink()
        else:
            key = re.sub(r"\d+", "#", outcome)[:90]
            if key not in findings:
                findings[key] = str(keep / path.name)
                if path.parent != keep:
                    (keep / path.name).write_bytes(path.read_bytes())
                print(f"  {kind}: {outcome}  ({keep / path.name})", flush=True)
            if path.parent != keep or key in findings and findings[key] != str(path):
                path.unlink(missing_ok=True)
    return {"kind": kind, "copies": n, "seed": seed, "counts": counts, "findings": findings}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated, of {', '.join(KINDS)}")
    ap.add_argument("--n", type=int, default=200, help="damaged copies per kind")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--osim", choices=("gait2392", "rajagopal"), default="gait2392",
                    help="the .osim the osim kind damages")
    ap.add_argument("--keep", type=Path, default=Path(tempfile.gettempdir()) / "calibrate-fuzz",
                    help="where the copies behind findings are kept")
    ap.add_argument("--json", type=Path, help="write the counts and findings here")
    a = ap.parse_args()
    kinds = [k for k in a.kinds.split(",") if k]
    unknown = [k for k in kinds if k not in KINDS]
    if unknown:
        ap.error(f"unknown kind {unknown[0]}; use {', '.join(KINDS)}")
    warnings.simplefilter("ignore")
    np.seterr(all="ignore")
    results = []
    for kind in kinds:
        r = fuzz(kind, a.n, a.seed, a.keep, a.osim)
        print(f"{kind:12s} {a.n} copies: " + ", ".join(f"{v} {k}" for k, v in sorted(r["counts"].items())))
        results.append(r)
    if a.json:
        a.json.write_text(json.dumps({"results": results}, indent=1))
    return 1 if any(r["findings"] for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
