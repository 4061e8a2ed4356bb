"""Simulated subjects: the base model's geometry perturbed (scales, joint centres, axes, markers),
sized to a stature, and the stature of a model."""

from __future__ import annotations

import math

import numpy as np

from ..errors import ModelError
from ..io.measurements import lateral_markers_of
from ..model.kinematics import Kinematics, build_kinematics
from ..model.model import Model, Parameters, hinge_axis

SCALE_RANGE = 0.10  # ± fraction


CENTRE_RANGE = 0.015  # ± m per coordinate


AXIS_TILT_DEG = 5.0  # max tilt of hinge axes


MARKER_RANGE = 0.010  # ± m per coordinate


SIZE_SPREAD = 0.04  # ± fraction: per-segment factors around the overall one when a stature is asked for


def perturb_parameters(model: Model, rng: np.random.Generator) -> Parameters:
    """A random plausible subject: the base model's parameters with the documented changes."""
    p = model.parameters()
    scale = 1.0 + rng.uniform(-SCALE_RANGE, SCALE_RANGE, p.scale.shape)
    centre = p.centre + rng.uniform(-CENTRE_RANGE, CENTRE_RANGE, p.centre.shape)
    marker = p.marker + rng.uniform(-MARKER_RANGE, MARKER_RANGE, p.marker.shape)
    axis = p.axis.copy()
    hinge_dofs = [model.dof_index(j.dofs[0]) for j in model.joints if j.kind == "hinge"]
    for i in hinge_dofs:
        axis[i] = tilt(axis[i], math.radians(rng.uniform(0.3, 1.0) * AXIS_TILT_DEG), rng)
    return hinges_by_their_landmarks(model, p, Parameters(scale, centre, axis, marker))


def hinges_by_their_landmarks(model: Model, base: Parameters, params: Parameters) -> Parameters:
    """`params` with each knee's Plug-in Gait lateral marker (LKNE, RKNE) moved across the knee's axis to the base
    model's offset from its centre, and each ankle's two malleoli markers (a pair straddling it in the base model,
    calibrate.problem.priors.straddle) moved together so that their midpoint is, their distances along the axis and
    their span kept: the markers sit over the epicondyle and the malleoli, which the flexion axis passes through,
    wherever a subject's centre lies (calibrate.problem.priors' landmark_terms holds a calibrated knee and ankle
    so)."""
    from ..problem.priors import straddle

    marker = params.marker.copy()

    def moved(ji: int, d: int, x0: np.ndarray, x: np.ndarray) -> np.ndarray:
        """How far the point x (the base model's x0) moves for its offset across the hinge's axis from the centre to
        be the base model's."""
        a0, a = hinge_axis(model, base, d), hinge_axis(model, params, d)
        y0, y = base.centre[ji] - x0, params.centre[ji] - x
        return (y - a * float(a @ y)) - (y0 - a0 * float(a0 @ y0))

    for name, label in lateral_markers_of(model, ("knee",)):
        ji, mi = model.joint_index(name), model.marker_index(label)
        d = model.dof_index(model.joints[ji].dofs[0])
        a0, a = hinge_axis(model, base, d), hinge_axis(model, params, d)
        y0 = base.centre[ji] - base.marker[mi]
        y = params.centre[ji] - params.marker[mi]
        marker[mi] = params.centre[ji] - a * float(a @ y) - (y0 - a0 * float(a0 @ y0))
    for ji, j in enumerate(model.joints):
        if j.kind != "hinge" or "ankle" not in j.name.lower():
            continue
        d = model.dof_index(j.dofs[0])
        on = [k for k, mk in enumerate(model.markers) if mk.segment == j.parent]
        a0 = hinge_axis(model, base, d)
        pairs = [(off, k1, k2) for n, k1 in enumerate(on) for k2 in on[n + 1:]
                 if (off := straddle(base.centre[ji], a0, base.marker[k1], base.marker[k2])) is not None]
        if pairs:
            _, k1, k2 = min(pairs)
            v = moved(ji, d, 0.5 * (base.marker[k1] + base.marker[k2]), 0.5 * (params.marker[k1] + params.marker[k2]))
            marker[k1], marker[k2] = params.marker[k1] + v, params.marker[k2] + v
    return Parameters(params.scale, params.centre, params.axis, marker)


def tilt(axis: np.ndarray, angle: float, rng: np.random.Generator) -> np.ndarray:
    """Unit `axis` tilted by `angle` (rad) towards a random perpendicular direction."""
    a = axis / np.linalg.norm(axis)
    v = rng.normal(size=3)
    v -= (v @ a) * a
    v /= np.linalg.norm(v)
    return math.cos(angle) * a + math.sin(angle) * v


def sized_subject(model: Model, params: Parameters, height: float, rng: np.random.Generator,
                  spread: float = SIZE_SPREAD) -> Parameters:
    """`params` with every segment's scale replaced by c·(1 + u), u uniform in ±`spread` per segment
    (the proportions vary) and c the one overall factor that makes the stature (see `stature`)
    exactly `height` (m).  Joint centres, axes and marker offsets are kept (positions scale with c)."""
    s = 1.0 + rng.uniform(-spread, spread, params.scale.shape)
    p = Parameters(s, params.centre, params.axis, params.marker)
    c = height / stature(model, p)  # the stature is linear in the scales (every length is)
    return Parameters(c * s, params.centre, params.axis, params.marker)


def human_landmarks() -> tuple[float, float, float]:
    """Neck, ankle and vertex heights of calibrate.model.human's reference subject (m)."""
    from ..model.human import MIDLINE_LANDMARKS, RIGHT_LANDMARKS

    return MIDLINE_LANDMARKS["neck"][2], RIGHT_LANDMARKS["ankle"][2], MIDLINE_LANDMARKS["vertex"][2]


def stature(model: Model, params: Parameters, kin: Kinematics | None = None) -> float:
    """The stature (m) of a subject of a calibrate.model.human-style model: in the neutral pose, the
    height of the neck joint centre above the mean of the ankle centres, plus the sole-to-ankle and
    neck-to-vertex heights of calibrate.model.human's proportions (0.07 and 0.25 of the neck-to-ankle
    1.43 of its 1.75 m reference) sized to the base model and multiplied by the scales of the feet
    (calcn) and the head.  The base model itself: its generator's height (1.75 m for models/human.urdf).  Any other
    model (an OpenSim model's): by its legs' length (_leg_stature)."""
    names = [j.name for j in model.joints]
    segs = [s.name for s in model.segments]
    need_j, need_s = ("neck", "ankle_r", "ankle_l"), ("head", "calcn_r", "calcn_l")
    if not all(n in names for n in need_j) or not all(n in segs for n in need_s):
        return _leg_stature(model, params, kin)
    kin = kin or build_kinematics(model)

    def neck_above_ankles(p: Parameters) -> float:
        _, c = kin.batch(np.zeros((1, model.nz)), np.array([[0.0, 0.0, 0.0, 1.0]]), p)
        z = c[0, :, 2]
        return float(z[names.index("neck")] - 0.5 * (z[names.index("ankle_r")] + z[names.index("ankle_l")]))

    neck, ankle, vertex = human_landmarks()
    k0 = neck_above_ankles(model.parameters()) / (neck - ankle)  # the base model's size vs the reference
    foot = 0.5 * (params.scale[segs.index("calcn_r")] + params.scale[segs.index("calcn_l")])
    head = params.scale[segs.index("head")]
    return neck_above_ankles(params) + k0 * (ankle * foot + (vertex - neck) * head)


#: Hip joint centre and ankle heights as fractions of the stature (Drillis & Contini's segment proportions, as
#: tabulated by Winter, Biomechanics and Motor Control of Human Movement: the greater trochanter 0.530 H, the ankle
#: 0.039 H): models/human.urdf's legs give 1.752 m by it against its 1.75, Rajagopal2016's 1.64 m.
LEG_FRACTION = 0.530 - 0.039


def _leg_stature(model: Model, params: Parameters, kin: Kinematics | None = None) -> float:
    """The stature (m) of a model that is not calibrate.model.human-style (an OpenSim model's: no neck joint or head
    segment; y up): the distance from the mean of its ankle centres to the mean of its hip centres in the neutral pose,
    over LEG_FRACTION."""
    names = [j.name for j in model.joints]
    hips = [i for i, n in enumerate(names) if n.lower().startswith("hip") and n.lower()[-2:] in ("_r", "_l")]
    ankles = [i for i, n in enumerate(names) if n.lower().startswith("ankle") and n.lower()[-2:] in ("_r", "_l")]
    if len(hips) != 2 or len(ankles) != 2:
        raise ModelError(f"{model.path}: a stature needs two hips and two ankles (joints named hip_r / hip_l and "
                         "ankle_r / ankle_l), or a calibrate.model.human model; leave the height out")
    kin = kin or build_kinematics(model)
    _, c = kin.batch(np.zeros((1, model.nz)), np.array([[0.0, 0.0, 0.0, 1.0]]), params)
    return float(np.linalg.norm(c[0, hips].mean(axis=0) - c[0, ankles].mean(axis=0))) / LEG_FRACTION
