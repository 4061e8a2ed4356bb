"""A subject's anthropometric measurements as a gait lab records them for Vicon's Plug-in Gait: body mass,
height and the caliper widths of knees, ankles, elbows and wrists, which Vicon Nexus writes into every
C3D file of the session (parameter group PROCESSING: ``Bodymass`` in kg, ``Height`` and ``LKneeWidth``,
``RAnkleWidth``, ... in mm; ``MarkerDiameter`` in mm where the session sets it).

Plug-in Gait puts each knee, ankle and elbow centre half the joint's width plus the marker's radius
medial of the lateral marker (KNE, ANK, ELB); the calibration uses the same measurements for what the
markers cannot show: where along its hinge axis a joint centre lies (calibrate.problem.gauge,
Problem.slide_centres), and the subject's mass for the segments' masses and inertias."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from calibrate.model.model import Model, Parameters

#: Plug-in Gait's marker diameter (mm) where the file does not state one (Vicon's 14 mm markers).
DEFAULT_MARKER_DIAMETER = 0.014

#: Joint (without side) -> (the width's name in PROCESSING without its L/R prefix, the lateral marker's
#: Plug-in Gait label without its prefix).  The wrist's markers sit on both styloids, not beside the axis.
WIDTHS = {"knee": ("KneeWidth", "KNE"), "ankle": ("AnkleWidth", "ANK"), "elbow": ("ElbowWidth", "ELB"),
          "wrist": ("WristWidth", None)}

#: The joints whose width places their centre along the hinge axis (Problem.slide_centres; a hinge the slide cannot
#: move, its child held, by a row in the solve: Problem.unslid_width_terms): Plug-in Gait's knee, ankle and elbow, the
#: measured width where the lab gave it, else the population's (Priors.population_width: the base model's lateral
#: marker's distance at the segment's scale).  The elbow's measured width was left out beside movement trials until
#: 2026-12-06 (sliding the elbow slides the forearm's contents back: pig_walk's radioulnar centre ended 70 mm from the
#: base model's offset, 11-30; with that day's fit 33-35 mm, the public walks' flagged elbows at their measurements),
#: and its population width until 2026-12-07: models/human.urdf's LELB sat 35 mm from the centre, short of the four
#: measured subjects' 47-55; at 48 mm, beside the public walks with their widths set aside, the six moving elbows end
#: 29.2 -> 6.1 mm RMS from their measurements (docs/benchmarks.md, "The elbows' population width").
WIDTH_JOINTS = ("knee", "ankle", "elbow")

#: Plausible ranges (SI): a value outside (or 0, which Nexus writes for "not measured") is not taken.
_RANGES = {"mass": (10.0, 400.0), "height": (0.5, 2.6), "width": (0.02, 0.30), "marker_diameter": (0.003, 0.05)}


@dataclass(frozen=True)
class SubjectMeasurements:
    """What the lab measured on the subject (SI units; None or absent: not measured).

    `widths`: joint name as models/human.urdf names it (``knee_l``, ``ankle_r``, ``elbow_l``, ``wrist_r``)
    -> the joint's width across its lateral and medial landmarks (m).  `marker_diameter`: the session's
    marker diameter (m), None when the file does not state it.  `source`: where they were read."""

    mass: float | None = None
    height: float | None = None
    widths: Mapping[str, float] = field(default_factory=dict)
    marker_diameter: float | None = None
    source: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "widths", {str(k): float(v) for k, v in dict(self.widths).items()})

    @property
    def empty(self) -> bool:
        """Nothing measured."""
        return self.mass is None and self.height is None and not self.widths

    def lateral_distance(self, joint: str) -> float | None:
        """Plug-in Gait's distance (m) from a knee, ankle or elbow centre to the lateral marker beside it: half
        the joint's width plus the marker's radius (the stated diameter, else DEFAULT_MARKER_DIAMETER)."""
        w = self.widths.get(joint)
        if w is None or WIDTHS.get(joint[:-2], (None, None))[1] is None:
            return None
        return 0.5 * w + 0.5 * (self.marker_diameter or DEFAULT_MARKER_DIAMETER)

    def as_dict(self) -> dict:
        """For the report: mm and kg."""
        return {"source": self.source, "mass_kg": self.mass,
                "height_mm": None if self.height is None else 1000 * self.height,
                "widths_mm": {k: 1000 * v for k, v in sorted(self.widths.items())},
                "marker_diameter_mm": 1000 * (self.marker_diameter or DEFAULT_MARKER_DIAMETER),
                "marker_diameter_stated": self.marker_diameter is not None}


def _number(group: Mapping, name: str) -> float | None:
    try:
        flat = np.asarray(group[name]["value"], dtype=float).ravel()
    except (KeyError, TypeError, ValueError):
        return None
    return float(flat[0]) if flat.size and np.isfinite(flat[0]) else None


def _plausible(kind: str, value: float | None) -> float | None:
    lo, hi = _RANGES[kind]
    return value if value is not None and lo <= value <= hi else None


def measurements_from_c3d(params: Mapping, source: str | None = None) -> SubjectMeasurements | None:
    """The subject measurements in a C3D file's parameters (ezc3d's ``c3d["parameters"]``), or None when its
    PROCESSING group carries none.  Nexus writes 0 for what was not measured: left out, as is a value
    outside a human range."""
    group = params.get("PROCESSING") if isinstance(params, Mapping) else None
    if not isinstance(group, Mapping):
        return None
    mass = _plausible("mass", _number(group, "Bodymass"))
    height = _number(group, "Height")
    height = _plausible("height", None if height is None else height / 1000)
    widths = {}
    for joint, (name, _) in WIDTHS.items():
        for prefix, side in (("L", "l"), ("R", "r")):
            w = _number(group, prefix + name)
            w = _plausible("width", None if w is None else w / 1000)
            if w is not None:
                widths[f"{joint}_{side}"] = w
    d = _number(group, "MarkerDiameter")
    d = _plausible("marker_diameter", None if d is None else d / 1000)
    out = SubjectMeasurements(mass, height, widths, d, source)
    return None if out.empty else out


def c3d_processing(m: SubjectMeasurements) -> dict[str, float]:
    """The PROCESSING parameters (Nexus's names and units: kg, mm) that measurements_from_c3d reads back."""
    out: dict[str, float] = {}
    if m.mass is not None:
        out["Bodymass"] = m.mass
    if m.height is not None:
        out["Height"] = 1000 * m.height
    for joint, (name, _) in WIDTHS.items():
        for prefix, side in (("L", "l"), ("R", "r")):
            if f"{joint}_{side}" in m.widths:
                out[prefix + name] = 1000 * m.widths[f"{joint}_{side}"]
    if m.marker_diameter is not None:
        out["MarkerDiameter"] = 1000 * m.marker_diameter
    return out


def lateral_markers_of(model: Model, joints=tuple(WIDTHS)) -> list[tuple[str, str]]:
    """(joint, lateral marker) for each of `joints` (knee, ankle, elbow; left then right) that `model` has as a
    hinge with the Plug-in Gait lateral marker (LKNE, RANK, ...) on the segment it hangs from."""
    hinges = {j.name: j for j in model.joints if j.kind == "hinge"}
    on = {mk.name: mk.segment for mk in model.markers}
    out = []
    for joint in joints:
        label = WIDTHS[joint][1]
        for side, prefix in (("l", "L"), ("r", "R")):
            name, marker = f"{joint}_{side}", prefix + (label or "")
            if label is not None and name in hinges and on.get(marker) == hinges[name].parent:
                out.append((name, marker))
    return out


def first_measurements(trials) -> SubjectMeasurements | None:
    """The first trial's measurements that has any (a session's trials carry the same)."""
    for t in trials:
        if getattr(t, "measurements", None) is not None:
            return t.measurements
    return None


def lateral_distance(model: Model, params: Parameters, base: Parameters, joint: str, marker: str) -> float:
    """A hinge joint's lateral marker's distance from the joint centre along the hinge axis (m) in geometry
    `params`, counted towards the side where the base geometry `base` has the marker (what a measured joint
    width fixes: calibrate.io.measurements)."""
    ji = next(i for i, j in enumerate(model.joints) if j.name == joint)
    mi = model.marker_names.index(marker)
    from calibrate.model.model import hinge_axis

    jt = model.joints[ji]
    d = model.dof_index(jt.dofs[0])

    def along(p) -> float:
        a = hinge_axis(model, p, d)
        return float(a @ (p.marker[mi] - p.centre[ji])) * float(p.scale[model.segment_index(jt.parent)])

    side = 1.0 if along(base) >= 0 else -1.0
    return side * along(params)
