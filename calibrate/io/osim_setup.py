"""A lab's OpenSim Inverse Kinematics setup file, read for what calibrate can use of it: the coordinates its
IK holds (``calibrate TRIAL ... MODEL --ik-setup subject01_Setup_IK.xml``) and the frames it fits.

OpenSim's IK weighs each ``IKCoordinateTask`` against the markers; labs use them, at weights of 1000 against
the markers' 1-10, to hold what their marker set cannot resolve at a value (Gait2392's pipeline holds both
subtalar and metatarsophalangeal angles at 0).  calibrate has no per-coordinate weight: each applied
coordinate task locks its coordinate (``Settings.lock``) at its value (``default_value``: the model's
default; ``manual_value``: the task's value).  ``from_file`` values, which change over the trial, are
refused.  The file's marker tasks (weights, markers left out of IK) are not used: calibrate learns each
marker's noise from the trial, and a marker OpenSim's IK leaves out may still help the scaling (a medial
knee marker of the static trial).

A lab's Scale setup file gives the subject's body mass and the marker set the Scale tool adds to the generic
model (``--scale-setup subject01_Setup_Scale.xml``): the mass scales the subject's segment masses and inertias
(what the lab's ID, Static Optimization and CMC setups read from the subject .osim); its measurement pairs and
marker weights are not used: calibrate scales and places the markers from every frame it is given.  Its marker
placer's coordinate tasks of weight POSE_TASK_WEIGHT or more are the static's pose (``static_pose``,
``setup_pose``): OpenSim places the markers on the model so posed, and calibrate turns the segment frames so that
the static's mean angles are those values (a change of gauge; the fit is unchanged).

Both setups name a trial file and the time range the lab chose in it (``marker_file``, ``time_range``: the
static's still second, the walk's cycle): each is a ``TimeRange``, and ``apply_time_ranges`` cuts the trials
the setups name to them, so that calibrate fits the frames the lab's Scale and IK tools fit (gait2392's
pipeline: 61 of the static's 300 frames, 121 of the walk's 151).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import ModelError, TrialError
from .osim_read import xml_element, xml_root
from .trial import Trial


def ik_setup_locks(path: str | Path, model) -> tuple[tuple[str, float], ...]:
    """(coordinate, value in rad or m) for every applied IKCoordinateTask of the IK setup at `path`, for
    `model` (its DoFs by OpenSim's coordinate names; ``default_value`` is the model's default).  Raises
    ModelError with one line on a file that is not an IK setup, a task on a coordinate the model does not
    have, or a value read from a file."""
    path = Path(path)
    tool = _ik_tool(path)
    return tuple(_coordinate_values(path, tool, model, root_ok=True)[0])


def ik_setup_notes(path: str | Path | Sequence[str | Path], model) -> list[str]:
    """A line per IK setup at `path` (one or several) whose coordinate tasks name the ground joint's coordinates,
    which no lock can hold (the root's pose is every frame's own, fitted to its markers): what ``--ik-setup`` says
    it leaves."""
    lines = []
    for one in _paths(path):
        tool = _ik_tool(one)
        held, root = _coordinate_values(one, tool, model, root_ok=True)
        if root:
            lines.append(f"{one.name}: its tasks on {', '.join(root)} (the ground joint's) are not held: the root's "
                         "pose is each frame's own, fitted to its markers")
        light = _light_tasks(one, tool, {n for n, _ in held})
        if light:
            lines.append(f"{one.name}: its tasks on {', '.join(f'{n} (weight {w:g})' for n, w in light)} weigh less "
                         f"than {POSE_TASK_WEIGHT:g}{_marker_weights(tool)}: OpenSim's IK lets the markers pull "
                         f"{'that coordinate' if len(light) == 1 else 'those coordinates'} a little off the value; "
                         "calibrate holds it there in every frame (remove the task to leave it free)")
    return lines


def _light_tasks(path: Path, tool, names: set[str]) -> list[tuple[str, float]]:
    """(coordinate, weight) of the applied coordinate tasks under `tool` on `names` lighter than POSE_TASK_WEIGHT."""
    out = []
    for task in tool.iter("IKCoordinateTask"):
        if _applied(task) and task.get("name", "") in names:
            w = _weight(path, task)
            if w < POSE_TASK_WEIGHT:
                out.append((task.get("name", ""), w))
    return out


def _marker_weights(tool) -> str:
    """' (its marker tasks weigh A-B)', or '' where it has no applied marker task with a readable weight."""
    weights = []
    for task in tool.iter("IKMarkerTask"):
        try:
            weights.append(float(task.findtext("weight") or 1.0))
        except ValueError:
            continue
        if not _applied(task):
            weights.pop()
    if not weights:
        return ""
    lo, hi = min(weights), max(weights)
    return f" (its marker tasks weigh {lo:g}" + (f"-{hi:g})" if hi > lo else ")")


POSE_TASK_WEIGHT = 100.0  # a marker placer's coordinate task this heavy defines the static's angle (Gait2392's: 1000)


def _coordinate_values(path: Path, tool, model, root_ok: bool = False) -> tuple[list[tuple[str, float]], list[str]]:
    """(coordinate, value in rad or m) of every applied IKCoordinateTask under `tool` (an IK tool, or a Scale
    setup's MarkerPlacer), for `model`: ``default_value`` the model's default, ``manual_value`` the task's value (in
    OpenSim's internal units, as its IK reads it; as the URDF's angle where a lumped chain turns by a ratio).
    ModelError with one line on a task on a coordinate the model
    does not have, a value read from a file, or a value that is not finite.  `root_ok`: tasks on the ground joint's
    coordinates are returned apart (second list) instead (a static pose's: the root's frame is its markers')."""
    from .osim_info import osim_info

    info = osim_info(model)
    defaults = info.defaults if info is not None else {}
    dofs = set(model.dof_names)
    root = {n for n, _ in info.root.rotations + info.root.translations} if (
        root_ok and info is not None and info.root is not None) else set()
    out: list[tuple[str, float]] = []
    at_root: list[str] = []
    for task in tool.iter("IKCoordinateTask"):
        name = task.get("name", "")
        if not _applied(task):
            continue
        if name in root:
            at_root.append(name)
            continue
        if name not in dofs:
            dropped = info is not None and name in info.dropped
            raise ModelError(f"{path}: coordinate task '{name}' names " + (
                "a coordinate the import made a function of another (coupled) or froze; remove the task"
                if dropped else f"no coordinate of {model.path.name}; is the setup for this model?"))
        mix = info.mixes.get(name) if info is not None else None
        if mix is not None and mix.independent not in info.locked:  # type: ignore[union-attr]
            raise ModelError(f"{path}: coordinate task '{name}' holds a coordinate whose joint the import also turns "
                             f"by {mix.independent} (the coupled {mix.dependent} folded onto it), which moves freely "
                             f"here; remove the task, or lock {mix.independent} in the model too")
        kind = (task.findtext("value_type") or "default_value").strip()
        if kind == "default_value":
            value = defaults.get(name, 0.0)
        elif kind == "manual_value":
            try:  # in the URDF's angle (a lumped chain's whole turn: OpenSim's value times its ratio)
                value = float(task.findtext("value") or 0.0) * (info.ratio(name) if info is not None else 1.0)
                if mix is not None:  # the folded turn at the locked value of its coordinate (OsimInfo.urdf_angle)
                    value += mix.mix * info.locked[mix.independent] / info.ratio(mix.independent)  # type: ignore
            except ValueError:
                value = math.nan
        else:
            raise ModelError(f"{path}: coordinate task '{name}' takes its value {kind!r}; calibrate holds a coordinate "
                             f"at one value (default_value or manual_value): change the task or lock it with --lock")
        if not math.isfinite(value):
            raise ModelError(f"{path}: coordinate task '{name}' has value {task.findtext('value')!r}; give a finite "
                             "value")
        out.append((name, value))
    return out, at_root


@dataclass(frozen=True)
class StaticPose:
    """What a lab's Scale setup says its static shows: the MarkerPlacer's trial file and the coordinates its
    coordinate tasks hold there (OpenSim places the markers on the model posed so).  calibrate turns the segment
    frames so that the trial's mean angles are these (``calibrate(..., neutral=K, pose=...)``): the data fit is
    unchanged, the angles' zero is the lab's."""

    setup: Path
    file: str  # the MarkerPlacer's marker_file, as the setup names it
    values: tuple[tuple[str, float], ...]  # (coordinate, rad or m)
    root: tuple[str, ...] = ()  # the ground joint's coordinates it names: not set (the root's frame is its markers')
    #: (coordinate, weight) of the tasks lighter than POSE_TASK_WEIGHT: a preference OpenSim weighs against the
    #: markers (Hamner's 1-10 against its markers' 10-100), which settles between the two; not applied
    soft: tuple[tuple[str, float], ...] = ()

    def text(self) -> str:
        """'lumbar_extension 0 deg, mtp_angle_r 0 deg'."""
        return ", ".join(f"{n} {math.degrees(v):.3g} deg" for n, v in self.values)


def static_pose(path: str | Path, model) -> StaticPose | None:
    """The static pose the Scale setup at `path` asks of `model` (its applied MarkerPlacer's coordinate tasks and
    trial; StaticPose), or None where the MarkerPlacer is not applied, names no trial or holds no coordinate.
    ModelError with one line as for an IK setup's tasks (ik_setup_locks)."""
    path = Path(path)
    tool = _scale_tool(path)
    placer = tool.find("MarkerPlacer")
    if placer is None or not _applied(placer):
        return None
    name = (placer.findtext("marker_file") or "").strip()
    values, root = _coordinate_values(path, placer, model, root_ok=True)
    weight = {t.get("name", ""): _weight(path, t) for t in placer.iter("IKCoordinateTask") if _applied(t)}
    soft = tuple((n, weight[n]) for n, _ in values if weight[n] < POSE_TASK_WEIGHT)
    values = [(n, v) for n, v in values if weight[n] >= POSE_TASK_WEIGHT]
    if not name or name == "Unassigned" or not (values or soft):
        return None
    return StaticPose(path, name, tuple(values), tuple(root), soft)


def _weight(path: Path, task) -> float:
    """A task's <weight> (1 where the file leaves it out); ModelError with one line when it is not a number >= 0."""
    text = (task.findtext("weight") or "1").strip()
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise ModelError(f"{path}: task '{task.get('name', '')}' has weight {text!r}; give a number >= 0")
    return value


def setup_pose(path: str | Path, model, trials: Sequence[Trial], names: Sequence[str] | None = None
               ) -> tuple[int | None, dict[str, float] | None, list[str]]:
    """What ``--scale-setup`` passes to calibrate as its ``neutral`` and ``pose``: the trial the Scale setup at `path`
    poses (static_pose, pose_trial) and the coordinates it holds there, and a line saying so (or why not: its trial
    not among `trials`); (None, None, []) where the setup holds no coordinate.  `names` as for pose_trial."""
    pose = static_pose(path, model)
    if pose is None:
        return None, None, []
    soft = (f"; its lighter tasks ({', '.join(f'{n} weight {w:g}' for n, w in pose.soft)}) are preferences OpenSim "
            f"weighs against the markers, not applied (calibrate holds those of weight {POSE_TASK_WEIGHT:g} or more)"
            if pose.soft else "")
    root = (f"; not {', '.join(pose.root)} (the ground joint's: the root's frame is where its markers put it)"
            if pose.root and pose.values else "")
    if not pose.values:
        return None, None, [f"{pose.setup.name}: no coordinate held in {pose.file}" + soft]
    k = pose_trial(pose, trials, names)
    if k is None:
        return None, None, [f"{pose.setup.name}: its MarkerPlacer poses {pose.file}, not among the trials; its "
                            f"coordinate tasks ({pose.text()}) not applied"]
    return k, dict(pose.values), [f"{pose.setup.name}: in {pose.file} its MarkerPlacer holds {pose.text()}: the "
                                  "segment frames are turned so at the end (as OpenSim places the markers; the fit "
                                  "is unchanged)" + root + soft]


def pose_trial(pose: StaticPose, trials: Sequence[Trial], names: Sequence[str] | None = None) -> int | None:
    """The index of the trial the static pose names (by file name, else by stem, as apply_time_ranges matches a
    range); None when it is not among them.  `names`: the trials' file names when not their ``source``."""
    names = [Path(t.source or "").name for t in trials] if names is None else [Path(n).name for n in names]
    want = Path(pose.file.replace("\\", "/")).name
    hit = [i for i, n in enumerate(names) if n == want] or [
        i for i, n in enumerate(names) if Path(n).stem == Path(want).stem]
    return hit[0] if hit else None


def ik_setup_weights(path: str | Path | Sequence[str | Path]) -> dict[str, float]:
    """Each marker's weight in the IK setup(s) at `path` (its IKMarkerTasks; 0 for a task not applied), as
    OpenSim's IK weighs the markers.  Two setups that weigh one marker differently: ModelError with one line."""
    weights: dict[str, float] = {}
    where: dict[str, Path] = {}
    for one in _paths(path):
        tool = _ik_tool(one)
        for task in tool.iter("IKMarkerTask"):
            name = task.get("name", "")
            try:
                value = float(task.findtext("weight") or 0.0) if _applied(task) else 0.0
            except ValueError:
                raise ModelError(f"{one}: marker task '{name}' has weight {task.findtext('weight')!r}; give a "
                                 "number") from None
            if not (math.isfinite(value) and value >= 0):
                raise ModelError(f"{one}: marker task '{name}' has weight {value}; give a number >= 0")
            if name in weights and weights[name] != value:
                raise ModelError(f"{one}: weighs marker {name} {value:g}, and {where[name].name} {weights[name]:g}; "
                                 "make the setups agree")
            weights[name], where[name] = value, Path(one)
    return weights


def with_ik_setup(model, settings, path: str | Path | Sequence[str | Path]):
    """`settings` with the held coordinates of the IK setup at `path` (or of several: a lab keeps one per trial)
    added to Settings.lock (those the settings already lock keep their values).  Two setups that hold one
    coordinate at different values: ModelError with one line naming both."""
    from dataclasses import replace

    held: dict[str, float] = {}
    where: dict[str, Path] = {}
    for one in _paths(path):
        for name, value in ik_setup_locks(one, model):
            if name in held and not math.isclose(held[name], value, rel_tol=0.0, abs_tol=1e-12):
                raise ModelError(f"{one}: its task holds {name} at {value:g}, and {where[name].name}'s at "
                                 f"{held[name]:g} (rad or m); make the setups agree, or hold it with --lock {name}=DEG")
            held[name], where[name] = value, Path(one)
    merged = {**held, **dict(settings.lock)}
    return replace(settings, lock=tuple(sorted(merged.items())))


def _tool(path: Path, tag: str, read_as: str, give: str, missing: str):
    """The <tag> element of the setup at `path` (xml_element), its task sets read in (_inline_task_sets)."""
    return _inline_task_sets(path, xml_element(path, tag, read_as, give, missing))


def _ik_tool(path: Path):
    """The <InverseKinematicsTool> of the IK setup at `path` (_tool; one line naming the file if it is not one)."""
    return _tool(path, "InverseKinematicsTool", "an OpenSim IK setup file (.xml)",
                 "an OpenSim Inverse Kinematics setup file",
                 "give the IK setup file (e.g. subject01_Setup_IK.xml), not a Scale or other setup")


def _scale_tool(path: Path):
    """The <ScaleTool> of the Scale setup at `path` (_tool; one line naming the file if it is not one)."""
    return _tool(path, "ScaleTool", "an OpenSim Scale setup file (.xml)", "an OpenSim Scale setup file",
                 "give the Scale setup file (e.g. subject01_Setup_Scale.xml), not an IK or other setup")


def _inline_task_sets(path: Path, element):
    """`element` with every <IKTaskSet file="..."> filled with the tasks of that file (read against the setup's
    folder, as OpenSim reads it: OpenSim's GUI writes a Scale setup's tasks so, e.g. gait2354_Scale_Tasks.xml).
    ModelError with one line when the file is not there or holds no IKTaskSet."""
    for ts in list(element.iter("IKTaskSet")):
        name = (ts.get("file") or "").strip()
        if not name or name == "Unassigned":
            continue
        where = Path(name) if Path(name).is_absolute() else path.parent / name
        if not where.is_file():
            raise ModelError(f"{path}: its task set file '{name}' is not at {where}; put it there, or write the "
                             "tasks into the setup")
        root = xml_root(where, "an OpenSim IK task set file (.xml)", "an OpenSim IK task set file")
        tasks = root if root.tag == "IKTaskSet" else root.find(".//IKTaskSet")
        if tasks is None:
            raise ModelError(f"{where}: no <IKTaskSet>; give the task set file the setup {path.name} names")
        for child in list(tasks):
            ts.append(child)
    return element


def _number(text: str | None) -> str:
    """The first number of `text` as '%g' ('1.14724'); the text itself where it is no number."""
    first = (text or "").split()[0] if (text or "").split() else ""
    try:
        return f"{float(first):g}"
    except ValueError:
        return first


def _task_value(task) -> str:
    """What a coordinate task holds its coordinate at, in words: 'the model's default', '0.1', 'from_file'."""
    kind = (task.findtext("value_type") or "default_value").strip()
    if kind != "manual_value":
        return "the model's default" if kind == "default_value" else kind
    text = (task.findtext("value") or "0").strip()
    try:
        return f"{float(text):g}"
    except ValueError:
        return text


def _paths(path: str | Path | Sequence[str | Path] | None) -> list[Path]:
    """One setup path or several, as a list (none for None)."""
    if path is None:
        return []
    return [Path(path)] if isinstance(path, (str, Path)) else [Path(p) for p in path]


@dataclass(frozen=True)
class TimeRange:
    """The frames of one trial file a step of a lab's OpenSim setup uses (its ``marker_file`` and ``time_range``)."""

    setup: Path  # the setup file
    step: str  # 'ModelScaler', 'MarkerPlacer' (a Scale setup) or 'InverseKinematicsTool'
    file: str  # the trial file as the setup names it
    start: float  # s, as the file's Time column counts
    stop: float  # s

    def text(self) -> str:
        """'1 to 2 s', for the lines that say what was cut."""
        return f"{self.start:g} to {self.stop:g} s"


@dataclass(frozen=True)
class ScaleSetup:
    """What calibrate takes from a lab's OpenSim Scale setup file (its ScaleTool)."""

    path: Path
    mass: float | None  # kg, the subject's body mass (<mass>); None where the file leaves it unset (0, -1)
    marker_set: Path | None  # the GenericModelMaker's marker_set_file, against the setup's folder; None: 'Unassigned'
    #: The static's frames its applied ModelScaler and MarkerPlacer use (none where a step names no file or its
    #: range is OpenSim's "whole file", -1 -1).
    ranges: tuple[TimeRange, ...] = ()
    #: The ModelScaler's preserve_mass_distribution.  calibrate always keeps the distribution (every segment's
    #: mass scaled alike to the subject's); false, OpenSim would first scale each segment's mass by its size.
    preserve_mass: bool = True


def scale_setup(path: str | Path) -> ScaleSetup:
    """The subject's mass and the marker set named by the OpenSim Scale setup at `path` (a relative marker set path
    is read against the setup's folder, as OpenSim's Scale tool reads it).  Raises ModelError with one line on a
    file that is not a Scale setup, a mass that is not a number, or a marker set file that is not there."""
    path = Path(path)
    tool = _scale_tool(path)
    text = (tool.findtext("mass") or "").strip()
    mass = None
    if text:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise ModelError(f"{path}: <mass> '{text}' is not a number; give the subject's body mass in kg")
        mass = value if value > 0 else None
    name = (tool.findtext("GenericModelMaker/marker_set_file") or "").strip()
    marker_set = None
    if name and name != "Unassigned":
        marker_set = Path(name) if Path(name).is_absolute() else path.parent / name
        if not marker_set.is_file():
            raise ModelError(f"{path}: its marker set file '{name}' is not at {marker_set}; put it there, or give "
                             f"the marker set with --marker-set")
    ranges = tuple(r for step in ("ModelScaler", "MarkerPlacer")
                   if (el := tool.find(step)) is not None and _applied(el)
                   and (r := _time_range(path, step, el)) is not None)
    preserve = (tool.findtext("ModelScaler/preserve_mass_distribution") or "true").strip().lower() != "false"
    return ScaleSetup(path, mass, marker_set, ranges, preserve)


def ik_setup_range(path: str | Path) -> TimeRange | None:
    """The trial file and time range the OpenSim IK setup at `path` fits (None: no file named, or the whole file).
    ModelError with one line on a file that is not an IK setup or a time range that is not two numbers."""
    path = Path(path)
    tool = _ik_tool(path)
    return _time_range(path, "InverseKinematicsTool", tool)


def _applied(element) -> bool:
    return (element.findtext("apply") or "true").strip().lower() == "true"


def _time_range(path: Path, step: str, element) -> TimeRange | None:
    """`element`'s marker_file and time_range as a TimeRange; None when it names no file ('Unassigned', empty) or
    its range is the whole file (OpenSim's -1 -1, or none given)."""
    name = (element.findtext("marker_file") or "").strip()
    text = (element.findtext("time_range") or "").split()
    if not name or name == "Unassigned" or not text:
        return None
    try:
        start, stop = (float(v) for v in text)
    except ValueError:
        raise ModelError(f"{path}: the {step}'s time_range '{' '.join(text)}' is not two numbers; give the start "
                         "and end time in seconds") from None
    if start == -1 and stop == -1:
        return None
    return TimeRange(path, step, name, start, stop)


def apply_time_ranges(trials: Sequence[Trial], ranges: Sequence[TimeRange | None],
                      names: Sequence[str] | None = None) -> tuple[list[Trial], list[str]]:
    """The trials with each one a setup names cut to its time range (to the span of all its ranges where two steps
    name it, as a Scale setup's ModelScaler and MarkerPlacer may), and one line per setup range saying what was cut
    or that its file is not among the trials.  A range names a trial by its file name, else by its stem (the .c3d
    of a setup's .trc); `names`: the trials' file names when not their ``source`` (a copy read in the lab's
    stead); a None in `ranges` (ik_setup_range of a setup that cuts nothing) is passed over.  TrialError with one
    line when a range lies outside its trial."""
    names = [Path(t.source or "").name for t in trials] if names is None else [Path(n).name for n in names]
    out, lines = list(trials), []
    spans: dict[int, list[TimeRange]] = {}
    for r in ranges:
        if r is None:
            continue
        want = Path(r.file.replace("\\", "/")).name
        hit = [i for i, n in enumerate(names) if n == want] or [
            i for i, n in enumerate(names) if Path(n).stem == Path(want).stem]
        if not hit:
            lines.append(f"{r.setup.name}: its {r.step} names {r.file}, not among the trials; its time range "
                         f"{r.text()} not applied")
            continue
        spans.setdefault(hit[0], []).append(r)
    for i, rs in spans.items():
        start, stop = min(r.start for r in rs), max(r.stop for r in rs)
        before = out[i].n_frames
        setups = sorted({r.setup.name for r in rs})
        try:
            out[i] = out[i].time_range(start, stop)
        except TrialError as e:  # the setup named, and the way round it
            raise TrialError(f"{', '.join(setups)}: {e}; or pass --whole-trials") from None
        steps = " and ".join(dict.fromkeys(r.step for r in rs))
        lines.append(f"{', '.join(setups)}: {names[i]} cut to {start:g} to {stop:g} s, {out[i].n_frames} of its "
                     f"{before} frames (the {steps}'s time range; --whole-trials to use every frame)")
    return out, lines


def cut_to_setups(trials: Sequence[Trial], scale: ScaleSetup | None,
                  ik: str | Path | Sequence[str | Path] | None) -> tuple[list[Trial], list[str]]:
    """The trials cut to the spans a lab's Scale setup (read by scale_setup) and IK setups (a path or several, one
    per trial) fit, and the lines saying so (apply_time_ranges): what ``--scale-setup`` and ``--ik-setup`` do to
    the trials."""
    return apply_time_ranges(trials, [*(scale.ranges if scale is not None else ()),
                                      *(ik_setup_range(one) for one in _paths(ik))])


#: What to do about an output a lab's setup names (--setup-names) that is there already.
SETUP_NAMED_HINT = "the lab's setup names it (an earlier OpenSim run's output?); pass --overwrite to replace it"


@dataclass(frozen=True)
class SetupOutputs:
    """Where a lab's OpenSim Scale and IK setups have OpenSim write the subject and the motions, each path resolved
    against its setup's folder as OpenSim resolves it: where ``--setup-names`` writes calibrate's, so that the lab's
    later setups (ID, Static Optimization, CMC) find them unchanged."""

    model: Path | None  # the subject .osim: the Scale setup's MarkerPlacer output_model_file (else its ModelScaler's)
    markers: Path | None  # the subject's markers as a MarkerSet file: the MarkerPlacer's output_marker_file
    motions: dict[str, Path]  # trial file name (as the setup names it) -> its .mot (MarkerPlacer's, IK setups')
    errors: dict[str, Path]  # trial file name -> <IK tool's name>_ik_marker_errors.sto in its results_directory
    setups: dict[str, Path]  # trial file name -> the setup naming its outputs
    # trial file name -> the markers its IK setup tracks (marker tasks applied, weight > 0): those OpenSim's IK fits
    # and reports the errors of (a marker with no task is not fitted: gait2392's walk with its Sternum task removed
    # counts 30 markers where it counted 31); absent for a setup without marker tasks
    tracked: dict[str, tuple[str, ...]] = field(default_factory=dict)
    scales: Path | None = None  # the segments' scale factors as a ScaleSet file: the ModelScaler's output_scale_file
    # trial file name -> <IK tool's name>_ik_model_marker_locations.sto in its results_directory, where the IK setup
    # asks for the model's marker locations (report_marker_locations true; OpenSim's default is false)
    locations: dict[str, Path] = field(default_factory=dict)

    def _key(self, trial: Path) -> str | None:
        """The name a setup gives the trial file `trial`: its file name, else its stem (the .c3d of a setup's .trc),
        as its time range names it; None where no setup names it."""
        return trial.name if trial.name in self.setups else next(
            (k for k in self.setups if Path(k).stem == trial.stem), None)

    def outputs_of(self, trial: Path, mot: Path, errors: Path) -> tuple[Path, Path]:
        """The .mot and marker-errors paths of the trial file `trial`: those its setup names, else `mot`, `errors`."""
        key = self._key(trial)
        return (mot, errors) if key is None else (self.motions.get(key, mot), self.errors.get(key, errors))

    def locations_of(self, trial: Path) -> Path | None:
        """Where the IK setup of the trial file `trial` has OpenSim write the model's marker locations; None where no
        setup names the trial or its setup does not ask for them."""
        key = self._key(trial)
        return None if key is None else self.locations.get(key)

    def tracked_of(self, trial: Path) -> tuple[str, ...] | None:
        """The markers the IK setup of the trial file `trial` tracks; None where no IK setup names it."""
        key = self._key(trial)
        return None if key is None else self.tracked.get(key)


def _output_name(element, tag: str) -> str | None:
    """`element`'s <tag> text, None where it names nothing (empty, 'Unassigned')."""
    text = (element.findtext(tag) or "").strip() if element is not None else ""
    return None if not text or text == "Unassigned" else text.replace("\\", "/")


def _against(setup: Path, name: str) -> Path:
    """`name` read against the folder of `setup`, as OpenSim reads a setup's file names ('IK/../Scale/x.osim' said
    'Scale/x.osim')."""
    return Path(name) if Path(name).is_absolute() else Path(os.path.normpath(setup.parent / name))


def scale_setup_inputs(path: str | Path) -> tuple[Path | None, Path | None]:
    """The generic model and the static trial the OpenSim Scale setup at `path` names (GenericModelMaker's model_file;
    the MarkerPlacer's marker_file, else the ModelScaler's), each read against the setup's folder as OpenSim reads
    them; None for one it leaves Unassigned.  ModelError with one line on a file that is not a Scale setup."""
    path = Path(path)
    tool = _scale_tool(path)
    model = _output_name(tool.find("GenericModelMaker"), "model_file")
    static = next((name for step in ("MarkerPlacer", "ModelScaler") if (el := tool.find(step)) is not None
                   and _applied(el) and (name := _output_name(el, "marker_file"))), None)
    return (None if model is None else _against(path, model)), (None if static is None else _against(path, static))


def ik_setup_inputs(path: str | Path) -> tuple[Path | None, Path | None]:
    """The model and the trial the OpenSim IK setup at `path` names (model_file, marker_file), each read against the
    setup's folder as OpenSim reads them; None for one it leaves Unassigned.  ModelError with one line on a file
    that is not an IK setup."""
    path = Path(path)
    tool = _ik_tool(path)
    model, trial = _output_name(tool, "model_file"), _output_name(tool, "marker_file")
    return (None if model is None else _against(path, model)), (None if trial is None else _against(path, trial))


def setup_outputs(scale: str | Path | None, ik: str | Path | Sequence[str | Path] | None) -> SetupOutputs:
    """The output names of the Scale setup `scale` and the IK setups `ik` (one per trial): see SetupOutputs.  A step
    not applied, or naming no trial file, names no motion; an IK setup's errors file only where it reports errors
    (report_errors, true unless set false), its model marker locations only where it reports them
    (report_marker_locations, false unless set true).  ModelError with one line on a file that is not such a setup."""
    model, markers, scales, motions, errors, setups, tracked, locations = None, None, None, {}, {}, {}, {}, {}
    if scale is not None:
        path = Path(scale)
        tool = _scale_tool(path)
        placer, scaler = tool.find("MarkerPlacer"), tool.find("ModelScaler")
        for step in (scaler, placer):  # the marker placer's model last: the lab's final subject
            if step is not None and _applied(step) and (name := _output_name(step, "output_model_file")):
                model = _against(path, name)
        if placer is not None and _applied(placer) and (name := _output_name(placer, "output_marker_file")):
            markers = _against(path, name)
        if scaler is not None and _applied(scaler) and (name := _output_name(scaler, "output_scale_file")):
            scales = _against(path, name)
        trial = _output_name(placer, "marker_file")
        if placer is not None and _applied(placer) and trial and (name := _output_name(placer, "output_motion_file")):
            motions[Path(trial).name], setups[Path(trial).name] = _against(path, name), path
    for one in _paths(ik):
        path = Path(one)
        tool = _ik_tool(path)
        trial = _output_name(tool, "marker_file")
        if not trial:
            continue
        key = Path(trial).name
        setups[key] = path
        if name := _output_name(tool, "output_motion_file"):
            motions[key] = _against(path, name)
        weights = ik_setup_weights(path)
        if weights:  # a setup with marker tasks tracks those it applies (a marker with no task is not fitted)
            tracked[key] = tuple(name for name, w in weights.items() if w > 0)
        results = _against(path, _output_name(tool, "results_directory") or ".")
        if (tool.findtext("report_errors") or "true").strip().lower() != "false":
            errors[key] = results / f"{tool.get('name') or path.stem}_ik_marker_errors.sto"
        if (tool.findtext("report_marker_locations") or "false").strip().lower() == "true":
            locations[key] = results / f"{tool.get('name') or path.stem}_ik_model_marker_locations.sto"
    return SetupOutputs(model, markers, motions, errors, setups, tracked, scales, locations)


def describe_setup(path: str | Path) -> list[str]:
    """Lines saying what calibrate takes from the OpenSim Scale or IK setup file at `path` and what it leaves
    (``calibrate inspect FILE.xml``).  ModelError with one line on a file that is neither."""
    path = Path(path)
    # A setup is an <OpenSimDocument> holding the tool, or (an older file: Hamner's Setup_Scale.xml) the tool itself.
    root = _inline_task_sets(path, xml_root(path, "an OpenSim setup file (.xml)", "an OpenSim Scale or IK setup file"))
    if root.tag == "ScaleTool" or root.find(".//ScaleTool") is not None:
        setup = scale_setup(path)
        tool = root if root.tag == "ScaleTool" else root.find(".//ScaleTool")
        pairs = len(tool.findall(".//MeasurementSet//MarkerPair"))
        scaler = tool.find("ModelScaler")
        manual = [f"{(sc.findtext('segment') or '').strip()} {_number(sc.findtext('scales'))}"
                  for sc in (scaler.iter("Scale") if scaler is not None else ())
                  if _applied(sc) and (sc.findtext("scales") or "").split()]
        order = (scaler.findtext("scaling_order") or "").split() if scaler is not None else []
        tasks = len(tool.findall(".//MarkerPlacer//IKMarkerTask"))
        cut = "; ".join(f"the {r.step} cuts {r.file} to {r.text()}" for r in setup.ranges)
        placer = tool.find("MarkerPlacer")
        held = [f"{t.get('name', '')} (" + _task_value(t) + (f", weight {_weight(path, t):g}: not applied" if
                _weight(path, t) < POSE_TASK_WEIGHT else "") + ")" for t in
                (placer.iter("IKCoordinateTask") if placer is not None and _applied(placer) else ()) if _applied(t)]
        return [f"{path}: an OpenSim Scale setup",
                "  --scale-setup takes: body mass " + (f"{setup.mass:g} kg" if setup.mass is not None else "unset")
                + ", marker set " + (str(setup.marker_set) if setup.marker_set is not None else "unset")
                + (f"; {cut} (--whole-trials: every frame)" if cut else "")
                + (f"; the static pose its MarkerPlacer holds in {placer.findtext('marker_file', '').strip()}: "
                   + ", ".join(held) + " (segment frames turned so)" if held else ""),
                f"  not used: its {pairs} measurement marker pairs, {tasks} marker-placer marker tasks and their "
                "weights" + (f", its manual scale factors ({', '.join(manual)})" if manual and "manualScale" in order
                             else "") + " (calibrate scales every segment and places every marker from the frames it "
                "is given)"
                + ("; preserve_mass_distribution false (calibrate scales every segment's mass alike)"
                   if not setup.preserve_mass else ""), *_named_lines(setup_outputs(path, None)),
                *_scaled_only_line(path, tool),
                *_alone_line(f"calibrate --scale-setup {path.name} [--ik-setup ...]", "calibrates {model} to {trial}",
                             *scale_setup_inputs(path))]
    tool = root if root.tag == "InverseKinematicsTool" else root.find(".//InverseKinematicsTool")
    if tool is None:
        hint = (f"an OpenSim MarkerSet is read with its model: calibrate inspect MODEL.osim --marker-set {path.name}"
                if root.find(".//MarkerSet") is not None else "give an OpenSim Scale or IK setup file")
        raise ModelError(f"{path}: neither a <ScaleTool> nor an <InverseKinematicsTool>; {hint}")
    held = []
    for task in tool.iter("IKCoordinateTask"):
        if not _applied(task):
            continue
        w = _weight(path, task)
        held.append(f"{task.get('name', '')} (" + _task_value(task) + (
            f", weight {w:g}: OpenSim weighs it against the markers" if w < POSE_TASK_WEIGHT else "") + ")")
    markers = [t for t in tool.iter("IKMarkerTask") if _applied(t)]
    span = ik_setup_range(path)
    return [f"{path}: an OpenSim IK setup",
            f"  --ik-setup locks {len(held)} coordinates its tasks hold: " + (", ".join(held) or "none")
            + (f"; cuts {span.file} to {span.text()} (--whole-trials: every frame)" if span is not None else ""),
            f"  not used: its {len(markers)} applied marker tasks and their weights (calibrate learns each marker's "
            "noise)", *_named_lines(setup_outputs(None, path)),
            *_alone_line(f"calibrate ik --ik-setup {path.name}", "fits {trial} with {model}", *ik_setup_inputs(path))]


def _alone_line(command: str, does: str, model: Path | None, trial: Path | None) -> list[str]:
    """describe_setup's line on the setup run alone, as OpenSim's tool runs it (`does`: a phrase with {model} and
    {trial}); none where it names no model or trial."""
    return [f"  alone: '{command}' " + does.format(model=model, trial=trial) + ", as OpenSim's tool runs the setup"] \
        if model is not None and trial is not None else []


def _scaled_only_line(path: Path, tool) -> list[str]:
    """describe_setup's line on the ModelScaler's model before marker placement, which calibrate does not write
    where the MarkerPlacer names the subject (calibrate scales the segments and places the markers in one solve)."""
    scaler, placer = tool.find("ModelScaler"), tool.find("MarkerPlacer")
    if scaler is None or placer is None or not (_applied(scaler) and _applied(placer)):
        return []
    only, placed = _output_name(scaler, "output_model_file"), _output_name(placer, "output_model_file")
    return [f"  --setup-names leaves out the ModelScaler's {_against(path, only)} (the model scaled before its "
            "markers are placed: calibrate scales the segments and places the markers in one solve, and writes the "
            "subject once)"] if only and placed else []


def _named_lines(named: SetupOutputs) -> list[str]:
    """describe_setup's line on where --setup-names writes what the setup names (none where it names nothing)."""
    parts = ([f"the subject {named.model}"] if named.model is not None else []) + \
        ([f"its markers {named.markers}"] if named.markers is not None else []) + \
        ([f"its scale factors {named.scales}"] if named.scales is not None else []) + \
        [f"{trial}'s motion {mot}" for trial, mot in named.motions.items()] + \
        [f"its marker errors {sto}" for sto in named.errors.values()] + \
        [f"its model marker locations {sto}" for sto in named.locations.values()]
    return [f"  --setup-names writes {', '.join(parts)}"] if parts else []


__all__ = ["POSE_TASK_WEIGHT", "SETUP_NAMED_HINT", "ScaleSetup", "SetupOutputs", "StaticPose", "TimeRange",
           "apply_time_ranges", "cut_to_setups", "describe_setup", "ik_setup_inputs", "ik_setup_locks",
           "ik_setup_notes", "ik_setup_range", "ik_setup_weights", "pose_trial", "scale_setup", "scale_setup_inputs",
           "setup_outputs", "setup_pose", "static_pose", "with_ik_setup"]
