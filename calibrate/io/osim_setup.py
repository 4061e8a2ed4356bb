"""A lab's OpenSim Inverse Kinematics setup file, read for what calibrate can use of it: the coordinates its
IK holds (``calibrate TRIAL ... MODEL --ik-setup subject01_Setup_IK.xml``).

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
(what the lab's ID, Static Optimization and CMC setups read from the subject .osim); its measurement pairs,
marker weights and static time range are not used: calibrate scales and places the markers from every frame of
the trials given.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from ..errors import ModelError
from .osim_read import xml_element


def ik_setup_locks(path: str | Path, model) -> tuple[tuple[str, float], ...]:
    """(coordinate, value in rad or m) for every applied IKCoordinateTask of the IK setup at `path`, for
    `model` (its DoFs by OpenSim's coordinate names; ``default_value`` is the model's default).  Raises
    ModelError with one line on a file that is not an IK setup, a task on a coordinate the model does not
    have, or a value read from a file."""
    path = Path(path)
    tool = xml_element(path, "InverseKinematicsTool", "an OpenSim IK setup file (.xml)",
                       "an OpenSim Inverse Kinematics setup file",
                       "give the IK setup file (e.g. subject01_Setup_IK.xml), not a Scale or other setup")
    from .osim_info import osim_info

    info = osim_info(model)
    defaults = info.defaults if info is not None else {}
    dofs = set(model.dof_names)
    locks: list[tuple[str, float]] = []
    for task in tool.iter("IKCoordinateTask"):
        name = task.get("name", "")
        if (task.findtext("apply") or "true").strip().lower() != "true":
            continue
        if name not in dofs:
            dropped = info is not None and name in info.dropped
            raise ModelError(f"{path}: coordinate task '{name}' names " + (
                "a coordinate the import made a function of another (coupled) or froze; remove the task"
                if dropped else f"no coordinate of {model.path.name}; is the setup for this model?"))
        kind = (task.findtext("value_type") or "default_value").strip()
        if kind == "default_value":
            value = defaults.get(name, 0.0)
        elif kind == "manual_value":
            value = float(task.findtext("value") or 0.0)
        else:
            raise ModelError(f"{path}: coordinate task '{name}' takes its value {kind!r}; calibrate holds a coordinate "
                             f"at one value (default_value or manual_value): change the task or lock it with --lock")
        if not math.isfinite(value):
            raise ModelError(f"{path}: coordinate task '{name}' has value {value}; give a finite value")
        locks.append((name, value))
    return tuple(locks)


def with_ik_setup(model, settings, path: str | Path):
    """`settings` with the IK setup's held coordinates added to Settings.lock (those the settings already lock
    keep their values)."""
    from dataclasses import replace

    have = dict(settings.lock)
    merged = {**dict(ik_setup_locks(path, model)), **have}
    return replace(settings, lock=tuple(sorted(merged.items())))


@dataclass(frozen=True)
class ScaleSetup:
    """What calibrate takes from a lab's OpenSim Scale setup file (its ScaleTool)."""

    path: Path
    mass: float | None  # kg, the subject's body mass (<mass>); None where the file leaves it unset (0, -1)
    marker_set: Path | None  # the GenericModelMaker's marker_set_file, against the setup's folder; None: 'Unassigned'


def scale_setup(path: str | Path) -> ScaleSetup:
    """The subject's mass and the marker set named by the OpenSim Scale setup at `path` (a relative marker set path
    is read against the setup's folder, as OpenSim's Scale tool reads it).  Raises ModelError with one line on a
    file that is not a Scale setup, a mass that is not a number, or a marker set file that is not there."""
    path = Path(path)
    tool = xml_element(path, "ScaleTool", "an OpenSim Scale setup file (.xml)", "an OpenSim Scale setup file",
                       "give the Scale setup file (e.g. subject01_Setup_Scale.xml), not an IK or other setup")
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
    return ScaleSetup(path, mass, marker_set)


def describe_setup(path: str | Path) -> list[str]:
    """Lines saying what calibrate takes from the OpenSim Scale or IK setup file at `path` and what it leaves
    (``calibrate inspect FILE.xml``).  ModelError with one line on a file that is neither."""
    path = Path(path)
    root = xml_element(path, "OpenSimDocument", "an OpenSim setup file (.xml)", "an OpenSim Scale or IK setup file",
                       "give an OpenSim Scale or IK setup file")
    if root.find(".//ScaleTool") is not None:
        setup = scale_setup(path)
        tool = root.find(".//ScaleTool")
        pairs = len(tool.findall(".//MeasurementSet//MarkerPair"))
        tasks = len(tool.findall(".//MarkerPlacer//IKMarkerTask"))
        times = (tool.findtext(".//MarkerPlacer/time_range") or "").split()
        return [f"{path}: an OpenSim Scale setup",
                "  --scale-setup takes: body mass " + (f"{setup.mass:g} kg" if setup.mass is not None else "unset")
                + ", marker set " + (str(setup.marker_set) if setup.marker_set is not None else "unset"),
                f"  not used: its {pairs} measurement marker pairs, {tasks} marker-placer marker tasks and their "
                "weights" + (f", the static's time range {_seconds(times)}" if len(times) == 2 else "")
                + " (calibrate scales every segment and places every marker from all frames of the trials given)"]
    tool = root.find(".//InverseKinematicsTool")
    if tool is None:
        hint = (f"an OpenSim MarkerSet is read with its model: calibrate inspect MODEL.osim --marker-set {path.name}"
                if root.find(".//MarkerSet") is not None else "give an OpenSim Scale or IK setup file")
        raise ModelError(f"{path}: neither a <ScaleTool> nor an <InverseKinematicsTool>; {hint}")
    held = []
    for task in tool.iter("IKCoordinateTask"):
        if (task.findtext("apply") or "true").strip().lower() != "true":
            continue
        kind = (task.findtext("value_type") or "default_value").strip()
        held.append(f"{task.get('name', '')} (" + ("the model's default" if kind == "default_value" else
                    f"{float(task.findtext('value') or 0.0):g}" if kind == "manual_value" else kind) + ")")
    markers = [t for t in tool.iter("IKMarkerTask") if (t.findtext("apply") or "true").strip().lower() == "true"]
    times = (tool.findtext("time_range") or "").split()
    return [f"{path}: an OpenSim IK setup",
            f"  --ik-setup locks {len(held)} coordinates its tasks hold: " + (", ".join(held) or "none"),
            f"  not used: its {len(markers)} applied marker tasks and their weights (calibrate learns each marker's "
            "noise)" + (f", the trial {tool.findtext('marker_file', '').strip()}" if tool.findtext("marker_file")
                        else "") + (f" and its time range {_seconds(times)}" if len(times) == 2 else "")
            + " (give the trials on the command line)"]


def _seconds(times: list[str]) -> str:
    try:
        return f"{float(times[0]):g} to {float(times[1]):g} s"
    except ValueError:
        return " to ".join(times)


__all__ = ["ScaleSetup", "describe_setup", "ik_setup_locks", "scale_setup", "with_ik_setup"]
