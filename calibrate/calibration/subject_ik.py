"""Every frame's pose of another trial of a subject already calibrated, the subject held fixed (``calibrate ik``).

What the calibration does to a trial before it fits it, and what a frame-by-frame fit still needs: the positions that
jump away and back (spikes, swapped labels), jitter, or stay behind while their segment moves (a marker fallen off)
left out (seed.seeding.jumped_samples' checks), two labels exchanged once and not back exchanged back where the
model's distances put them the wrong way round; the coordinates of segments the trial's markers cannot place held at 0
(model.resolve); then calibrate.solve.ik.inverse_kinematics.  A frame-by-frame fit has no outlier test of its own:
on pig_walk's walk one frame of a ghost 1.8 m off turned the right shoulder 230 deg, a marker fallen to the floor the
left knee 19 deg for the rest of the walk (scripts/damage_values.py --ik).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..errors import CalibrateError
from ..io.trial import Trial
from ..model.kinematics import build_kinematics, locked_balls
from ..model.model import Model, Parameters
from ..model.resolve import resolve
from ..problem.problem import LIMIT_MARGIN
from ..seed.jitter import Jittery
from ..seed.seeding import ExchangedBack, episodes, exchanged_back, without_broken
from ..solve.ik import IKResult, inverse_kinematics


@dataclass(frozen=True)
class TrialFit:
    """One trial fitted to a calibrated subject: the fit, the marker positions left out before it (how many), the
    markers that jitter (left out where they do), the coordinates held because the trial's markers do not place
    their segments (name -> value, rad), those segments, and the labels exchanged back (seeding.lone_exchanges)."""

    fit: IKResult
    left_out: int
    jittery: tuple[Jittery, ...]
    unplaced_held: dict[str, float]
    unplaced: tuple[str, ...]
    exchanged_back: tuple[ExchangedBack, ...] = ()


def fit_trial(model: Model, trial: Trial, params: Parameters, held: Mapping[str, float],
              weights: Mapping[str, float] | None = None, keep_damaged: bool = False,
              source: str = "the trial") -> TrialFit:
    """Fit every frame of `trial` (labels the model's: io.labels.map_labels) to `model` at `params`, holding `held`
    (coordinate -> rad or m), the markers weighed by `weights` (an IK setup's tasks; a marker without one is not
    fitted) or alike, under the calibration's limits (LIMIT_MARGIN).  `keep_damaged`: every position fitted, as
    OpenSim's IK does.  `source` names the trial in errors.  Raises CalibrateError when its markers cannot place the
    model's root."""
    shared = [m for m in model.marker_names if m in trial.labels and (weights is None or weights.get(m, 0) > 0)]
    left, jittery, back = 0, (), []
    if not keep_damaged:
        back: list[ExchangedBack] = []
        jumps, found = episodes(trial, model=model, back=back)
        trial = exchanged_back(trial, back)
        trial, left = without_broken(model, trial, jumps, broken=False)
        jittery = tuple(x for x in found if x.label in shared)
    seen = [m for m in shared if np.isfinite(trial.markers[:, trial.labels.index(m)]).all(axis=1).any()]
    # (a name the model lacks: inverse_kinematics' one line says so)
    res = resolve(model, seen, locked=[d for d in held if d in model.dof_names])
    if not res.root_resolved:
        raise CalibrateError(f"{source}: its {len(seen)} markers of {model.path.name} cannot place the {model.root} "
                             f"(unresolved: {', '.join(res.names)}); give the subject calibrated from this lab's "
                             "marker set")
    extra = {d: float(np.clip(0.0, model.dofs[model.dof_index(d)].lower, model.dofs[model.dof_index(d)].upper))
             for d in res.lock}
    held = {**held, **extra}
    kin = build_kinematics(model, euler=locked_balls(model, held))  # a ball with a held angle on its three angles
    fit = inverse_kinematics(kin, trial, params, locked=held, weights=weights, default_weight=0.0, margin=LIMIT_MARGIN)
    return TrialFit(fit, left, jittery, extra, res.names if extra else (), tuple(back))
