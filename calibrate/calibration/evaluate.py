"""A calibration against a simulation's known truth: the figures the demo, the benchmark and
the tests report.  Everything is compared in the lab frame, so the calibrated model may
come from any base model (e.g. one scaled 15 % too small).

* ball / universal joint centres: distance to the true centre, median over frames;
* hinge centres: distance to the true axis *line* (a hinge centre's place along its axis
  is not defined by any motion), median over frames;
* hinge axes: angle between the calibrated and true axis in the lab, median over frames;
* marker RMS: of the calibrated fit, and of the true subject model refitted frame by frame
  to the same noisy markers (the noise floor);
* joint angles: RMS difference from the true angles, over frames and DoFs, both as is and
  with each DoF's constant offset removed (a segment frame's turn that no marker data can
  fix is held by the priors, and shows as such an offset); and the same for the true subject
  model refitted frame by frame (the joint-angle noise floor: what the marker noise alone
  costs the angles of a frame-by-frame fit, whatever the model).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..model.blocks import FrameLayout
from ..model.kinematics import build_kinematics
from ..problem.options import ProblemOptions
from ..problem.problem import Problem
from ..problem.state import State
from ..seed.geometry import marker_rms
from ..simulation.simulate import Simulation, joint_axes_world
from ..solve.ik import marker_columns
from ..solve.lm import levenberg_marquardt
from .result import Calibration


@dataclass(frozen=True)
class TruthComparison:
    """Errors of a calibration against the truth (m, deg)."""

    centre_error: dict[str, float]  # joint -> m (hinge: distance from the true axis line)
    axis_error_deg: dict[str, float]  # hinge joint -> deg
    kinds: dict[str, str]
    marker_rms: float  # m, calibrated model
    floor_rms: float  # m, true model refitted per frame (what the noise alone gives)
    floor_angle_rms_deg: float  # the same fit's joint angles against the truth (nan if not computed)
    angle_rms_deg: float  # over frames and DoFs
    angle_rms_offset_free_deg: float
    angle_rms_per_dof_deg: dict[str, float]

    def ball(self) -> dict[str, float]:
        return {k: v for k, v in self.centre_error.items() if self.kinds[k] != "hinge"}

    def hinge(self) -> dict[str, float]:
        return {k: v for k, v in self.centre_error.items() if self.kinds[k] == "hinge"}


def true_model_floor(sim: Simulation) -> tuple[float, float]:
    """The true subject model refitted frame by frame to the noisy trial: its RMS marker error (m)
    and the RMS of its joint angles against the true ones (deg): the floors the noise sets."""
    model = sim.model
    obs = marker_columns(model, sim.trial)
    problem = Problem(model, obs, ProblemOptions(free=()), build_kinematics(model), base=sim.truth)
    m = sim.motion
    Z = FrameLayout.coordinates(m.root_translation, m.angles)
    state = State(Z, m.root_quaternion.copy(), sim.truth.vector())
    state, _ = levenberg_marquardt(problem, state, pose_only=True, max_iterations=20)
    res = problem.marker_residuals(state)
    Z, _ = problem.kin.absolute(state.Z, state.Q, state.B, previous=m.angles[0])
    dang = np.degrees(np.angle(np.exp(1j * (FrameLayout.angles(Z) - m.angles))))
    return marker_rms(res), float(np.sqrt(np.mean(dang**2)))


def true_marker_floor(sim: Simulation) -> float:
    """RMS marker error of the true subject model refitted frame by frame to the noisy trial (m)."""
    return true_model_floor(sim)[0]


def compare_to_truth(cal: Calibration, sim: Simulation, floor: float | None = None) -> TruthComparison:
    """Errors of `cal` (calibrated from `sim.trial`, possibly from another base model) against `sim`."""
    model = cal.model
    kin = build_kinematics(model)
    mo = cal.motion
    Z = FrameLayout.coordinates(mo.root_translation, mo.angles)
    _, C = kin.batch(Z, mo.root_quaternion, cal.params)
    true_index = {j.name: i for i, j in enumerate(sim.model.joints)}
    ax_est = joint_axes_world(model, cal.params, mo)
    ax_true = joint_axes_world(sim.model, sim.truth, sim.motion)
    centre, axis, kinds = {}, {}, {}
    for ji, j in enumerate(model.joints):
        ct = sim.clean_centres[:, true_index[j.name]]
        d = C[:, ji] - ct
        kinds[j.name] = j.kind
        if j.kind == "hinge":
            a = ax_true[j.name]
            d = d - np.sum(d * a, axis=1, keepdims=True) * a
            cosang = np.abs(np.sum(ax_est[j.name] * a, axis=1)).clip(0, 1)
            axis[j.name] = float(np.degrees(np.median(np.arccos(cosang))))
        centre[j.name] = float(np.median(np.linalg.norm(d, axis=1)))
    dang = np.degrees(np.angle(np.exp(1j * (mo.angles - sim.motion.angles))))
    per = np.sqrt(np.mean(dang**2, axis=0))
    centred = dang - dang.mean(axis=0)
    return TruthComparison(
        centre, axis, kinds, cal.marker_rms, *(true_model_floor(sim) if floor is None else (floor, math.nan)),
        float(np.sqrt(np.mean(dang**2))), float(np.sqrt(np.mean(centred**2))),
        dict(zip(model.dof_names, per.tolist(), strict=True)))
