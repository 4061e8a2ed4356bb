"""A lab's database calibrated in parallel on Dask: a manifest of subjects (trials, base model, marker map,
mass), one folder of outputs per subject, a summary CSV and an HTML index across subjects.

Each subject is one task on a dask.distributed cluster (a LocalCluster of worker processes by default,
or an existing cluster by its scheduler's address).  A subject that fails (a broken trial, a model
that does not fit) is reported with its one-line error and does not stop the others.  A subject whose
report JSON exists is done (the outputs are written all or none, the report among them) and is
skipped unless `overwrite`: a batch stopped half way is run again to finish it.  The per-frame
functions compiled for a model's structure are kept on disk (calibrate.problem.codegen) and loaded,
not compiled again, by every later subject on every worker; a worker process also keeps the base
models it read.

Manifest (TOML or CSV; paths relative to the manifest's folder):

    [[subject]]                       # TOML: one table per subject
    id = "S01"
    trials = ["S01/static.c3d", "S01/walk.c3d"]
    model = "models/human.urdf"       # or an OpenSim .osim
    markers = "labels.toml"           # optional: the lab's label map (calibrate --markers)
    mass = 68.0                       # optional: kg
    marker_set = "gait2392_Scale_MarkerSet.xml"   # optional, an .osim model only: as --marker-set
    ik_setup = "S01/Setup_IK.xml"                 # ... as --ik-setup (the coordinates it holds locked; a list:
                                                  #     one per trial)
    scale_setup = "S01/Setup_Scale.xml"           # ... as --scale-setup (mass and marker set, unless given)
    whole_trials = true                           # optional: as --whole-trials (not the setups' time ranges)
    setup_names = true                            # optional: as --setup-names (the subject .osim, its motions and
                                                  #     marker errors where the setups have OpenSim write them)
    # trials and model may be left out where scale_setup is given: those the setups name, setup_names then true
    hip_regression = "auto"                       # optional: true (--hip-regression), "auto" (--hip-regression-auto),
                                                  #     "outside" (the default), false (--no-hip-regression)
    config = "S01/settings.toml"                  # optional: the subject's settings file (calibrate --config)
    ik_trials = ["S01/walk2.c3d", "S01/*.trc"]    # optional: more trials fitted to the calibrated subject held
                                                  #     fixed, as calibrate ik --report does (<trial>_motion.csv,
                                                  #     <trial>_ik_report.json; .mot and .sto for an .osim model); a
                                                  #     pattern: every file it matches but the calibration trials

    config = "lab_settings.toml"      # TOML, before the first [[subject]]: the settings file of every subject
                                      # that names none

    subject,trials,model,markers,mass # CSV: trials (and IK setups) separated by ';', markers and mass may be
                                      # empty; optional
    S01,S01/static.c3d;S01/walk.c3d,models/human.urdf,,68   # columns marker_set, ik_setup, scale_setup,
                                                            # whole_trials, setup_names, hip_regression, config,
                                                            # ik_trials

An OpenSim base model's subject is also written as subject.osim, its motions as <trial>_motion.mot.
"""

from __future__ import annotations

import csv
import functools
import html
import io
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from ..errors import CalibrateError
from .options import HIP_MODES

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPORT = "report.json"  # each subject's report: written last of its outputs, with them; marks it done
SUMMARY_COLUMNS = ("subject", "status", "marker_rms_mm", "iterations", "converged", "seconds", "warnings",
                   "implausible", "ik_trials", "ik_marker_rms_mm", "error", "folder")
IK_REPORT = "_ik_report.json"  # <trial>_ik_report.json: an ik trial's report, written last; it marks the trial done
_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
OPENSIM_FILES = ("marker_set", "ik_setup", "scale_setup")  # a subject's OpenSim files (an .osim model only)


@dataclass(frozen=True)
class Subject:
    """One subject of a manifest: its trials (static and movement), base model, label map and mass."""

    id: str
    trials: tuple[Path, ...]
    model: Path
    markers: Path | None = None
    mass: float | None = None
    marker_set: Path | None = None  # an OpenSim model's MarkerSet file (calibrate --marker-set)
    ik_setup: tuple[Path, ...] = ()  # the lab's OpenSim IK setups (one per trial): what they hold locked (--ik-setup)
    scale_setup: Path | None = None  # the lab's OpenSim Scale setup: mass and marker set (--scale-setup)
    whole_trials: bool = False  # every frame, not the setups' time ranges (--whole-trials)
    # the subject .osim, its motions and marker errors where the setups have OpenSim write them (--setup-names)
    setup_names: bool = False
    # the hips by Harrington's regression: True (--hip-regression), "auto" only where they end implausible without it
    # (--hip-regression-auto; Settings.hip_regression), "outside" only where they end outside the pelvis, False never
    # (--no-hip-regression); None: the settings file's ("outside" without one)
    hip_regression: bool | str | None = None
    config: Path | None = None  # the subject's settings file (calibrate --config; io.config.load_settings)
    # more trials fitted to the calibrated subject held fixed (calibrate ik --report: calibration.ik_trials)
    ik_trials: tuple[Path, ...] = ()


def _flag(text: str, path: Path, subject: str, key: str = "whole_trials", auto: bool = False) -> bool | str:
    """A CSV manifest's true/false cell (`auto`: the hip_regression modes "auto" and "outside" too)."""
    value = text.strip().lower()
    if auto and value in HIP_MODES:
        return value
    if value not in ("true", "false", "1", "0", "yes", "no"):
        raise CalibrateError(f"{path}: subject {subject}: {key} {text.strip()!r} must be true or false"
                             + (', "auto" or "outside"' if auto else ""))
    return value in ("true", "1", "yes")


def _from_setups(base: Path, row: dict, where: str) -> dict:
    """A subject given by its OpenSim setups alone (no trials, no model): the generic model and static trial its
    Scale setup names and the trial each IK setup names, as OpenSim's tools run them, its outputs where they name them
    (setup_names, unless the row says otherwise), as ``calibrate --scale-setup S.xml --ik-setup I.xml`` takes them."""
    from ..io.osim_setup import ik_setup_inputs, scale_setup_inputs

    scale, iks = row["scale_setup"], row.get("ik_setup") or []
    iks = [v for v in iks.split(";") if v.strip()] if isinstance(iks, str) else iks
    if not isinstance(scale, str) or not isinstance(iks, list) or not all(isinstance(v, str) for v in iks):
        raise CalibrateError(f"{where}: 'scale_setup' and 'ik_setup' must name setup files")
    model, static = scale_setup_inputs(base / scale.strip())
    named = [(scale, "GenericModelMaker's model_file", model), (scale, "marker placer's marker_file", static),
             *((ik, "marker_file", ik_setup_inputs(base / ik.strip())[1]) for ik in iks)]
    for setup, what, got in named:
        if got is None:
            raise CalibrateError(f"{where}: {setup.strip()}'s {what} is Unassigned; name it in the setup, or give the "
                                 "subject's 'trials' and 'model'")
    return {"trials": [str(p) for p in dict.fromkeys(got for _, _, got in named[1:])], "model": str(model),
            "setup_names": row.get("setup_names", True)}


def read_manifest(path: str | os.PathLike[str], config: str | os.PathLike[str] | None = None) -> list[Subject]:
    """The subjects of a TOML or CSV manifest (module docstring); one-line CalibrateError if it is bad.  `config`:
    the settings file of every subject that names none of its own (calibrate batch --config), in place of the
    manifest's top-level `config`."""
    path = Path(path)
    if config is not None:
        from ..io.config import load_settings

        load_settings(config)  # refused in its own line before the manifest is read
    if not path.is_file():
        raise CalibrateError(f"{path}: no such manifest; give a .toml or .csv file (see docs/batch.md)")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise CalibrateError(f"{path}: cannot be read as text ({e}); give a .toml or .csv manifest") from None
    if path.suffix.lower() == ".toml":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise CalibrateError(f"{path}: not valid TOML ({e})") from None
        rows, top = data.get("subject"), data.get("config")
        if top is not None and (not isinstance(top, str) or not top.strip()):
            raise CalibrateError(f"{path}: 'config' must name a settings file (TOML, as calibrate --config), got "
                                 f"{top!r}")
        if not isinstance(rows, list) or not rows:
            raise CalibrateError(f"{path}: no [[subject]] tables; add one per subject (see docs/batch.md)")
    elif path.suffix.lower() == ".csv":
        reader = csv.DictReader(io.StringIO(text))
        missing = {"subject", "trials", "model"} - set(reader.fieldnames or ())
        if missing:
            raise CalibrateError(f"{path}: CSV header lacks {', '.join(sorted(missing))}; the columns are "
                                 "subject,trials,model,markers,mass (and, for an .osim model, "
                                 "marker_set,ik_setup,scale_setup)")
        rows = [{"id": r["subject"], "trials": [t for t in (r["trials"] or "").split(";") if t.strip()],
                 "model": r["model"], "markers": r.get("markers") or None,
                 "mass": float(r["mass"]) if (r.get("mass") or "").strip() else None,
                 **{k: r[k] for k in OPENSIM_FILES if (r.get(k) or "").strip()},
                 **({"whole_trials": _flag(r["whole_trials"], path, r["subject"])}
                    if (r.get("whole_trials") or "").strip() else {}),
                 **({"setup_names": _flag(r["setup_names"], path, r["subject"], "setup_names")}
                    if (r.get("setup_names") or "").strip() else {}),
                 **({"hip_regression": _flag(r["hip_regression"], path, r["subject"], "hip_regression", auto=True)}
                    if (r.get("hip_regression") or "").strip() else {}),
                 **({"config": r["config"]} if (r.get("config") or "").strip() else {}),
                 **({"ik_trials": [t for t in r["ik_trials"].split(";") if t.strip()]}
                    if (r.get("ik_trials") or "").strip() else {})} for r in reader]
        top = None
    else:
        raise CalibrateError(f"{path}: a manifest is a .toml or .csv file, not {path.suffix or 'one without suffix'}")
    base = path.parent
    subjects, seen = [], set()
    loaded: dict[Path, str] = {}  # each settings file read once: its one-line error, or "" if it reads
    for k, row in enumerate(rows, start=1):
        where = f"{path}: subject {k}"
        if not isinstance(row, dict):
            raise CalibrateError(f"{where}: expected a table of id, trials, model")
        sid = str(row.get("id", "")).strip()
        if not _ID.match(sid):
            raise CalibrateError(f"{where}: id {sid!r} must be letters, digits, '.', '_' or '-' (a folder name)")
        if sid in seen:
            raise CalibrateError(f"{where}: id {sid!r} appears twice; give each subject its own id")
        seen.add(sid)
        if row.get("trials") is None and row.get("model") is None and row.get("scale_setup") is not None:
            row = {**row, **_from_setups(base, row, f"{where} ({sid})")}
        trials = row.get("trials")
        if isinstance(trials, str):
            trials = [trials]
        if not trials or not all(isinstance(t, str) and t.strip() for t in trials):
            raise CalibrateError(f"{where} ({sid}): 'trials' must list one or more trial files")
        if not isinstance(row.get("model"), str) or not row["model"].strip():
            raise CalibrateError(f"{where} ({sid}): 'model' must name the base model (.urdf or .osim)")
        mass = row.get("mass")
        if mass is not None and (isinstance(mass, bool) or not isinstance(mass, (int, float)) or not mass > 0):
            raise CalibrateError(f"{where} ({sid}): 'mass' must be a positive number of kg, got {mass!r}")
        markers = row.get("markers")
        opensim = {}
        for key in OPENSIM_FILES:
            value = row.get(key)
            if value is None:
                continue
            many = key == "ik_setup"  # one IK setup per trial: a list, or (CSV) files separated by ';'
            items = ([v for v in value.split(";") if v.strip()] if many and isinstance(value, str)
                     else value if many else [value])
            if not isinstance(items, list) or not items or not all(isinstance(v, str) and v.strip() for v in items):
                raise CalibrateError(f"{where} ({sid}): '{key}' must name a file (an OpenSim {key.replace('_', ' ')})"
                                     + (", or list one per trial" if many else ""))
            if not row["model"].strip().lower().endswith(".osim"):
                raise CalibrateError(f"{where} ({sid}): '{key}' applies to an OpenSim base model (.osim), and "
                                     f"{row['model'].strip()} is not one; leave it out or give the .osim")
            opensim[key] = tuple(base / v.strip() for v in items) if many else base / items[0].strip()
        whole = row.get("whole_trials", False)
        if not isinstance(whole, bool):
            raise CalibrateError(f"{where} ({sid}): 'whole_trials' must be true or false, got {whole!r}")
        named = row.get("setup_names", False)
        if not isinstance(named, bool):
            raise CalibrateError(f"{where} ({sid}): 'setup_names' must be true or false, got {named!r}")
        if named and not ({"ik_setup", "scale_setup"} & set(opensim)):
            raise CalibrateError(f"{where} ({sid}): 'setup_names' takes the names the lab's setups give; add its "
                                 "ik_setup and/or scale_setup (an OpenSim base model's)")
        hips = row.get("hip_regression")
        if not (hips is None or isinstance(hips, bool) or hips in HIP_MODES):
            raise CalibrateError(f"{where} ({sid}): 'hip_regression' must be true, false, \"auto\" or \"outside\", "
                                 f"got {hips!r}")
        own = row.get("config")
        if own is not None and (not isinstance(own, str) or not own.strip()):
            raise CalibrateError(f"{where} ({sid}): 'config' must name a settings file (TOML, as calibrate --config), "
                                 f"got {own!r}")
        # The subject's own, else the command line's (`config`), else the manifest's.
        settings = (base / own.strip() if own is not None else Path(config) if config is not None
                    else None if top is None else base / top.strip())
        if settings is not None and settings not in loaded:
            # Read now, so that a bad settings file is refused before any subject's work, not in every task.
            from ..io.config import load_settings

            try:
                load_settings(settings)
                loaded[settings] = ""
            except CalibrateError as e:
                loaded[settings] = str(e)
        if settings is not None and loaded[settings]:
            raise CalibrateError(f"{where} ({sid}): {loaded[settings]}")
        more = row.get("ik_trials") or []
        more = [more] if isinstance(more, str) else more
        if not isinstance(more, list) or not all(isinstance(t, str) and t.strip() for t in more):
            raise CalibrateError(f"{where} ({sid}): 'ik_trials' must list trial files (fitted to the calibrated "
                                 f"subject), got {row.get('ik_trials')!r}")
        listed = _ik_trials(base, [t.strip() for t in trials], [t.strip() for t in more], f"{where} ({sid})")
        subjects.append(Subject(sid, tuple(base / t.strip() for t in trials), base / row["model"].strip(),
                                None if not markers else base / str(markers).strip(),
                                None if mass is None else float(mass), **opensim, whole_trials=whole,
                                setup_names=named, hip_regression=hips, config=settings,
                                ik_trials=tuple(listed)))
    return subjects


def _ik_trials(base: Path, trials: Sequence[str], listed: Sequence[str], where: str) -> list[Path]:
    """A subject's ik_trials as files: each entry a file, or a glob pattern (``S01/*.c3d``: every file it matches but
    the subject's calibration trials, in name order); refused (one line) where a pattern matches no file, a file named
    is a calibration trial too, or two share a name (each trial's outputs are named by its stem)."""
    import glob

    own = {(base / t).resolve(): t for t in trials}
    out: list[Path] = []
    for entry in listed:
        if glob.has_magic(entry):
            found = sorted(Path(f) for f in glob.glob(str(base / entry)) if Path(f).is_file())
            if not found:
                raise CalibrateError(f"{where}: ik_trials' pattern {entry} matches no file; check it against the "
                                     f"manifest's folder, {base}")
            out += [f for f in found if f.resolve() not in own]
        else:
            out.append(base / entry)
    out = list({f.resolve(): f for f in out}.values())  # a file both named and matched: once
    stems = {Path(t).stem: t for t in trials}
    for f in out:
        if f.stem in stems:
            what = ("is a calibration trial too (its motion is the calibration's)" if f.resolve() in own
                    else f"and {stems[f.stem]} have one name ({f.stem}_motion.csv)")
            raise CalibrateError(f"{where}: ik_trials' {f.relative_to(base) if f.is_relative_to(base) else f} {what}; "
                                 "list each trial once, under a name of its own")
        stems[f.stem] = str(f)
    return out


@functools.lru_cache(maxsize=8)
def _base_model(path: str, mtime: float, marker_set: str | None = None, marker_set_mtime: float = 0.0):
    """A base model (with an OpenSim model's marker set) read once per worker process (and again only if a file
    changed)."""
    from ..model.model import load_model

    return load_model(path, marker_set)


def _mtime(path: Path | None) -> float:
    return path.stat().st_mtime if path is not None and path.exists() else 0.0


def _opensim_outputs(folder: Path, trials: Sequence[Path], setups=None, at_setups: bool = False) -> dict:
    """A subject's OpenSim outputs (cal.write's osim, mot, errors, error_markers, marker_set and scale_set): in its
    folder, else (`at_setups`) where its setups name them (`setups`: calibrate.io.osim_setup.setup_outputs of the
    subject's setups, whose IK setups' tracked markers the errors count, as OpenSim's IK counts them)."""
    mots = [folder / f"{Path(t).stem}_motion.mot" for t in trials]
    errors = [folder / f"{Path(t).stem}_ik_marker_errors.sto" for t in trials]
    out = {"osim": folder / "subject.osim", "mot": mots, "errors": errors}
    if setups is None:
        return out
    out["error_markers"] = [setups.tracked_of(Path(t)) for t in trials]
    if at_setups:
        pairs = [setups.outputs_of(Path(t), m, e) for t, m, e in zip(trials, mots, errors, strict=True)]
        out.update(osim=setups.model or out["osim"], mot=[m for m, _ in pairs], errors=[e for _, e in pairs],
                   **({"marker_set": setups.markers} if setups.markers is not None else {}),
                   **({"scale_set": setups.scales} if setups.scales is not None else {}),
                   **({"marker_locations": [setups.locations_of(Path(t)) for t in trials]} if setups.locations
                      else {}))
    return out


def check_named(outputs: dict, folder: Path, replace_named: bool) -> None:
    """Refuse (one line) the setup-named outputs outside the subject's `folder` that exist (unless `replace_named`:
    the batch's --overwrite) or whose folder does not: the lab's files, checked before the subject's work."""
    from ..io.osim_setup import SETUP_NAMED_HINT
    from ..io.outputs import check_targets

    paths = [outputs["osim"], outputs.get("marker_set"), outputs.get("scale_set"), *outputs["mot"], *outputs["errors"],
             *outputs.get("marker_locations", ())]
    check_targets([p for p in paths if p is not None and not p.is_relative_to(folder)], replace_named,
                  exists_hint=SETUP_NAMED_HINT)


def subject_outputs(cal, folder: Path, trials: Sequence[Path], overwrite: bool, opensim: bool = False,
                    c3d: bool = False, mjcf: bool = False, setups=None, at_setups: bool = False,
                    replace_named: bool = False) -> dict:
    """Write one subject's outputs into `folder`, all or none: subject.urdf, one <trial>_motion.csv per
    trial (`opensim`: also subject.osim, a <trial>_motion.mot and a <trial>_ik_marker_errors.sto each, as calibrate
    writes them; `c3d`: a <trial>_calibrated.c3d each, as
    calibrate --c3d writes it; `mjcf`: subject_mujoco.xml and a <trial>_motion_qpos.csv each, as calibrate --mjcf
    writes them), the HTML report and, last, the report JSON (the subject's done-marker).  `setups`: the subject's
    OpenSim setups (calibrate.io.osim_setup.setup_outputs): the marker errors count the markers its IK setups track;
    `at_setups` (a subject's setup_names): the subject .osim, its marker set and scale factors, motions, marker
    errors and (where an IK setup asks) model marker locations where they name them, replaced there only with
    `replace_named` (they are the lab's files, outside the batch's folder)."""
    motions = [folder / f"{Path(t).stem}_motion.csv" for t in trials]
    extra = _opensim_outputs(folder, trials, setups, at_setups) if opensim else {}
    if at_setups and opensim:
        check_named(extra, folder, replace_named)
    if c3d:
        extra["c3d"] = [folder / f"{Path(t).stem}_calibrated.c3d" for t in trials]
    if mjcf:
        extra["mjcf"] = folder / "subject_mujoco.xml"
        extra["qpos"] = [m.with_name(m.stem + "_qpos.csv") for m in motions]
    return cal.write(urdf=folder / "subject.urdf", motion=motions, report=folder / REPORT,
                     html=folder / "report.html", overwrite=overwrite, **extra)


def report_row(report: dict) -> dict:
    """A subject's summary figures from its report JSON (calibration.report.calibration_report): marker RMS (mm),
    iterations, convergence, its warnings — what to look at: notes, parameters carried beyond their priors
    (unreliable), labels to check, label exchanges, non-convergence; not the parameters a trial leaves to the priors,
    as many for every subject of one protocol (24-50 on the real recordings), which hid the few that differ — and
    its implausible results (the summary's implausible lines, named, so a lab sorts its subjects by what to look at
    first)."""
    converged = bool(report["solver"]["converged"])
    warnings = (len(report["notes"]) + len(report["unreliable"]) + len(report["suspect_labels"])
                + len(report["jittery_markers"]) + len(report["exchanged_back"]) + len(report["trials_apart"])
                + len(report.get("places_apart") or [])
                + len(report["exchanged_labels"]) + len(report["relabelled"]) + (0 if converged else 1))
    return {"marker_rms_mm": float(report["markers"]["rms_mm"]), "iterations": int(report["solver"]["iterations"]),
            "converged": converged, "warnings": warnings,
            "implausible": list(report.get("implausible_flags") or [])}


def blank_row(sid: str) -> dict:
    """A subject's summary row before anything is known of it."""
    return {"subject": sid, "status": "", "marker_rms_mm": math.nan, "iterations": 0, "converged": False,
            "seconds": 0.0, "warnings": 0, "implausible": [], "ik_trials": 0, "ik_marker_rms_mm": math.nan,
            "error": "", "folder": sid}


def _line(e: BaseException) -> str:
    """An exception's first line (its type where it says nothing)."""
    return str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__


def _with_ik(row: dict, ik: dict) -> dict:
    """A subject's row with its ik trials' figures, their errors after its own."""
    errors = [row["error"], *ik["errors"]] if row["error"] else ik["errors"]
    return {**row, "ik_trials": ik["fitted"], "ik_marker_rms_mm": ik["worst_mm"], "error": " | ".join(errors)}


def subject_model_file(subject: Subject, folder: Path) -> Path:
    """The calibrated subject a batch wrote for `subject` into `folder`: subject.urdf, or for an OpenSim base model
    its subject.osim (where its setups name it with setup_names)."""
    if subject.model.suffix.lower() != ".osim":
        return folder / "subject.urdf"
    setups = None
    if subject.scale_setup is not None or subject.ik_setup:
        from ..io.osim_setup import setup_outputs

        setups = setup_outputs(subject.scale_setup, subject.ik_setup)
    return _opensim_outputs(folder, subject.trials, setups, subject.setup_names)["osim"]


def fit_ik_trials(subject: Subject, folder: Path, refit: bool = False, c3d: bool = False, mjcf: bool = False) -> dict:
    """Fit `subject`'s ik_trials to the subject calibrated into `folder`, held fixed, as ``calibrate ik TRIALS SUBJECT
    --report report.json [--markers MAP]`` fits them (calibration.ik_trials; the same bytes): <trial>_motion.csv and,
    last, <trial>_ik_report.json each (an OpenSim subject's <trial>_motion.mot and <trial>_ik_marker_errors.sto;
    `c3d`, `mjcf` as the calibration's trials).  A trial whose ik report exists is done and read back, unless
    `refit` (the subject was calibrated again).  Never raises: each trial's failure is one line, the others go on.
    Returns {"fitted": trials done, "worst_mm": the largest of their marker RMS (NaN: none), "errors": lines}."""
    from .ik_trials import IKFiles, fit_planned, plan_trials, write_fitted

    out = {"fitted": 0, "worst_mm": math.nan, "errors": []}
    if not subject.ik_trials:
        return out
    rms: list[float] = []
    model = None
    for path in subject.ik_trials:
        report = folder / f"{path.stem}{IK_REPORT}"
        try:
            if report.exists() and not refit:
                rms.append(float(json.loads(report.read_text(encoding="utf-8"))["markers"]["rms_mm"]))
                out["fitted"] += 1
                continue
            if model is None:
                from ..model.model import load_model

                model = load_model(subject_model_file(subject, folder))
            plan = plan_trials(model, [path], report=folder / REPORT, markers=subject.markers)
            one = fit_planned(plan, ahead=False)[0]  # (the batch's workers keep the cores busy)
            osim = plan.osim
            write_fitted(plan, one, IKFiles(
                folder / f"{path.stem}_motion.csv", report,
                folder / f"{path.stem}_motion.mot" if osim else None,
                folder / f"{path.stem}_ik_marker_errors.sto" if osim else None, None,
                folder / f"{path.stem}_calibrated.c3d" if c3d else None,
                folder / f"{path.stem}_motion_qpos.csv" if mjcf else None))
            rms.append(float(one.report["markers"]["rms_mm"]))
            out["fitted"] += 1
        except Exception as e:  # noqa: BLE001 - one trial's failure is reported, the others go on
            line = _line(e)
            out["errors"].append(line if path.name in line else f"{path.name}: {line}")
    if rms:
        out["worst_mm"] = max(rms)
    return out


def calibrate_subject(subject: Subject, out: str | os.PathLike[str], overwrite: bool = False,
                      c3d: bool = False, mjcf: bool = False) -> dict:
    """Calibrate one subject into out/<id>/ (a task on a worker): its summary row (`c3d`: each trial also as
    <trial>_calibrated.c3d; `mjcf`: the subject and its motions for MuJoCo).  Never raises: a failure is the row's
    status 'failed' with the error's one line."""
    folder = Path(out) / subject.id
    row = blank_row(subject.id)
    if (folder / REPORT).exists() and not overwrite:  # done before: its figures from its report (a resumed
        # batch's summary keeps them); its ik trials not fitted yet fitted now
        try:
            report = json.loads((folder / REPORT).read_text(encoding="utf-8"))
            done = {**report_row(report), "seconds": float(sum((report.get("times_s") or {}).values()))}
        except (OSError, ValueError, TypeError, KeyError, AttributeError):
            done = {}  # a report that does not read: skipped all the same, its figures blank
        return _with_ik({**row, **done, "status": "skipped"}, fit_ik_trials(subject, folder, c3d=c3d, mjcf=mjcf))
    t0 = time.perf_counter()
    try:
        setups = None
        if subject.scale_setup is not None or subject.ik_setup:
            from ..io.osim_setup import setup_outputs

            setups = setup_outputs(subject.scale_setup, subject.ik_setup)
        if subject.setup_names:  # the OpenSim outputs where the subject's setups have OpenSim write them
            check_named(_opensim_outputs(folder, subject.trials, setups, True), folder, overwrite)
        from ..io.config import load_settings
        from ..io.labels import load_marker_map
        from ..io.read import read_trial
        from ..problem.settings import Settings
        from .pipeline import calibrate

        setup = None
        if subject.scale_setup is not None:  # the lab's Scale setup: the subject's mass and its marker set
            from ..io.osim_setup import scale_setup

            setup = scale_setup(subject.scale_setup)
        marker_set = subject.marker_set if subject.marker_set is not None or setup is None else setup.marker_set
        mass = subject.mass if subject.mass is not None or setup is None else setup.mass
        model = _base_model(str(subject.model), _mtime(subject.model), None if marker_set is None else str(marker_set),
                            _mtime(marker_set))
        # The subject's settings file, the manifest's hip_regression over it; the workers keep the cores busy
        # already: nothing is run ahead in another process (Settings.ahead, whatever the file says).
        settings = replace(load_settings(subject.config) if subject.config is not None else Settings(), ahead=False,
                           **({} if subject.hip_regression is None else {"hip_regression": subject.hip_regression}))
        if subject.ik_setup:
            from ..io.osim_setup import with_ik_setup

            settings = with_ik_setup(model, settings, subject.ik_setup)
        trials = [read_trial(t) for t in subject.trials]
        if not subject.whole_trials and (setup is not None or subject.ik_setup):
            # The frames the lab's Scale and IK tools fit, as the command line cuts them (--whole-trials: every one).
            from ..io.osim_setup import cut_to_setups

            trials, _ = cut_to_setups(trials, setup, subject.ik_setup)
        marker_map = load_marker_map(subject.markers) if subject.markers else None
        neutral, pose = None, None
        if setup is not None:  # the static pose the lab's marker placer holds, as the command line takes it
            from ..io.osim_setup import setup_pose

            neutral, pose, _ = setup_pose(setup.path, model, trials, [Path(t).name for t in subject.trials])
        cal = calibrate(model, trials, settings, marker_map=marker_map, mass=mass, neutral=neutral, pose=pose)
        if setup is not None and subject.mass is None and mass is not None:
            cal = replace(cal, mass_from=str(setup.path))
        folder.mkdir(parents=True, exist_ok=True)
        subject_outputs(cal, folder, subject.trials, overwrite=True, opensim=subject.model.suffix.lower() == ".osim",
                        c3d=c3d, mjcf=mjcf, setups=setups, at_setups=subject.setup_names, replace_named=overwrite)
        done = report_row(json.loads((folder / REPORT).read_text(encoding="utf-8")))  # as written
        row = {**row, **done, "status": "ok" if cal.converged else "not converged",
               "seconds": time.perf_counter() - t0}
    except Exception as e:  # noqa: BLE001 - one subject's failure, whatever it is, is reported, not raised
        return {**row, "status": "failed", "seconds": time.perf_counter() - t0, "error": _line(e)}
    # its ik trials fitted again, whatever they were fitted to before (the subject is new)
    return _with_ik(row, fit_ik_trials(subject, folder, refit=True, c3d=c3d, mjcf=mjcf))


def run_batch(subjects: Sequence[Subject], out: str | os.PathLike[str], workers: int = 2,
              scheduler: str | None = None, overwrite: bool = False,
              progress: Callable[[dict, int, int], None] | None = None, c3d: bool = False,
              mjcf: bool = False) -> list[dict]:
    """Calibrate every subject on a Dask cluster (a LocalCluster of `workers` processes, one thread each,
    or the cluster at `scheduler`'s address); write out/summary.csv and out/index.html; the rows in the
    manifest's order.  `progress(row, done, total)` as each subject finishes; `c3d`: each trial also as
    <trial>_calibrated.c3d in its subject's folder; `mjcf`: subject_mujoco.xml and <trial>_motion_qpos.csv too."""
    from dask.distributed import Client, LocalCluster, as_completed

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if scheduler:
        client, cluster = Client(scheduler), None
    else:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    try:
        futures = {client.submit(calibrate_subject, s, str(out), overwrite, c3d, mjcf,
                                 key=f"calibrate-{s.id}-{time.time_ns()}", pure=False): s.id for s in subjects}
        rows: dict[str, dict] = {}
        for k, fut in enumerate(as_completed(futures), start=1):
            sid = futures[fut]
            try:
                row = fut.result()
            except Exception as e:  # noqa: BLE001 - a worker lost: the subject is reported, the others go on
                row = {**blank_row(sid), "status": "failed", "error": f"worker failed: {e}"}
            rows[sid] = row
            if progress is not None:
                progress(row, k, len(subjects))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    ordered = [rows[s.id] for s in subjects]
    write_summary(ordered, out)
    return ordered


def write_summary(rows: Sequence[dict], out: Path) -> None:
    """out/summary.csv (one row per subject) and out/index.html (the same, with links to each subject's
    HTML report and report JSON)."""
    from ..io.outputs import put_text, write_all

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{r[k]:.3f}" if isinstance(r[k], float) else " | ".join(r[k]) if isinstance(r[k], list)
                        else r[k]) for k in SUMMARY_COLUMNS})
    write_all({out / "summary.csv": lambda p: put_text(p, buf.getvalue()),
               out / "index.html": lambda p: put_text(p, index_html(rows, out))})


def index_html(rows: Sequence[dict], out: Path) -> str:
    """The HTML index across subjects: status, marker RMS, iterations, time, warnings, links."""
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "not converged", "failed", "skipped")}
    body = []
    for r in rows:
        sid = html.escape(r["subject"])
        links = []
        if (out / r["folder"] / "report.html").exists():
            links.append(f'<a href="{sid}/report.html">report</a>')
        if (out / r["folder"] / REPORT).exists():
            links.append(f'<a href="{sid}/{REPORT}">JSON</a>')
        rms = "" if not math.isfinite(r["marker_rms_mm"]) else f"{r['marker_rms_mm']:.2f}"
        ik = "" if not r["ik_trials"] else (f"{r['ik_trials']}" + (f" (worst {r['ik_marker_rms_mm']:.2f} mm)"
                                                                   if math.isfinite(r["ik_marker_rms_mm"]) else ""))
        cls = {"failed": "bad", "not converged": "bad"}.get(r["status"], "")
        body.append(f'<tr><td>{sid}</td><td class="{cls}">{html.escape(r["status"])}</td><td class="n">{rms}</td>'
                    f'<td class="n">{r["iterations"] or ""}</td><td class="n">{r["seconds"]:.1f}</td>'
                    f'<td class="n">{r["warnings"] or ""}</td>'
                    f'<td class="bad">{"<br>".join(html.escape(x) for x in r["implausible"])}</td>'
                    f'<td class="n">{ik}</td>'
                    f'<td>{" ".join(links)}</td>'
                    f'<td>{html.escape(r["error"])}</td></tr>')
    return ("<!doctype html><html><head><meta charset='utf-8'><title>calibrate batch</title><style>"
            "body{font-family:system-ui,sans-serif;margin:1.5em}table{border-collapse:collapse}"
            "td,th{border:1px solid #ddd;padding:2px 8px}th{background:#f3f3f3}td.n{text-align:right}"
            ".bad{color:#b00020}</style></head><body><h1>calibrate batch</h1>"
            f"<p>{len(rows)} subjects: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n) + "</p>"
            "<table><tr><th>subject</th><th>status</th><th>marker RMS (mm)</th><th>iterations</th>"
            "<th>time (s)</th><th>warnings</th><th>implausible</th><th>ik trials (marker RMS)</th><th>outputs</th>"
            "<th>error</th></tr>"
            + "".join(body) + "</table></body></html>\n")
