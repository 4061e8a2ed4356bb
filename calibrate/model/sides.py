"""Which side of the body a model's marker sits on, against the side its name says.

A lab's model can carry its own labelling slips: FullBodyModel_Hamner2010_v2_0.osim (opensim-models) puts
``LHJC`` at the right hip's centre and ``RHJC`` at the left's.  calibrate keeps a joint-centre marker at its
centre (calibrate.problem.priors.joint_centre_markers), so a trial's ``LHJC`` would be held at the right hip.
The side a name says: a leading ``L`` / ``R`` before a capital, digit or separator (``LASI``, ``L.ASIS``,
``R_HJC``), ``l_`` / ``r_``, ``left`` / ``right``, or a trailing ``_l`` / ``.R``.  The side the model puts it on:
its distance from the sagittal plane in the neutral pose (Pinocchio), the plane found from the segments paired
by name (``femur_l`` / ``femur_r``).  Units: metres.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .model import Model

SIDE_MARGIN = 0.02  # m: a marker this close to the sagittal plane sits on neither side

# A leading capital L / R before a capital, digit or separator ('Lumbar' names no side), l_ / r_, left / right;
# a trailing _l / .R.
_LEADING = re.compile(r"^(?:[LR](?=[A-Z0-9._\- ])|[lr][._\- ]|(?i:left|right))")
_TRAILING = re.compile(r"[._\- ][LRlr]$")


def named_side(label: str) -> str | None:
    """'left' or 'right' as the marker's name says it (module docstring), or None (no side, or both)."""
    sides = set()
    if (m := _LEADING.match(label)) is not None:
        sides.add("left" if m.group(0)[0] in "lL" else "right")
    if _TRAILING.search(label) is not None:
        sides.add("left" if label[-1] in "lL" else "right")
    return sides.pop() if len(sides) == 1 else None


def unsided(label: str) -> str:
    """The marker's name without the side its name says (named_side's token, at the start or the end)."""
    return _TRAILING.sub("", _LEADING.sub("", label, count=1))


@dataclass(frozen=True)
class SideMismatch:
    """A model marker whose name says one side while the model puts it on the other."""

    marker: str
    segment: str
    named: str  # 'left' or 'right', as its name says
    distance: float  # m from the sagittal plane, on the other side

    def text(self) -> str:
        other = "right" if self.named == "left" else "left"
        return (f"{self.marker} (on {self.segment}) sits {1000 * self.distance:.0f} mm {other} of the midline though "
                f"its name says {self.named}")


def side_mismatches(model: Model) -> tuple[SideMismatch, ...]:
    """The model's markers whose name says a side (named_side) and which the model, in its neutral pose, puts more
    than SIDE_MARGIN on the other side of its sagittal plane: the plane through the midpoints of the segment
    origins paired by name (X_l / X_r), normal to their mean left-to-right direction.  () where no segments are
    so paired."""
    names = {s.name for s in model.segments}
    pairs = [(n, n[:-2] + "_r") for n in sorted(names) if n.endswith("_l") and n[:-2] + "_r" in names]
    if not pairs:
        return ()
    lefts = model.neutral_positions([a for a, _ in pairs])
    rights = model.neutral_positions([b for _, b in pairs])
    lateral = np.sum(rights - lefts, axis=0)
    if np.linalg.norm(lateral) < 1e-9:
        return ()
    lateral /= np.linalg.norm(lateral)
    middle = np.mean((lefts + rights) / 2, axis=0)
    sided = [(mk, named) for mk in model.markers if (named := named_side(mk.name)) is not None]
    at = model.neutral_positions([mk.name for mk, _ in sided])
    out = []
    for (mk, named), p in zip(sided, at, strict=True):
        d = float((p - middle) @ lateral)  # > 0: right
        if (d < -SIDE_MARGIN and named == "right") or (d > SIDE_MARGIN and named == "left"):
            out.append(SideMismatch(mk.name, mk.segment, named, abs(d)))
    return tuple(out)
