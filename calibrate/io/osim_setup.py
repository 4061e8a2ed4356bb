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
"""

from __future__ import annotations

import math
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


__all__ = ["ik_setup_locks", "with_ik_setup"]
