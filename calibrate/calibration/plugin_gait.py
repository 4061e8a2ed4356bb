"""Plug-in Gait's knee axes checked against the motion its own bones record.

Vicon's Plug-in Gait builds the femur frame from the hip centre, the knee marker (KNE) and the thigh marker
(THI wand, or the KAD in the static); that frame's lateral axis is its knee flexion axis, and its knee centre
lies KneeWidth/2 + the marker radius medial of KNE along it.  A thigh marker off the plane the knee flexes in
turns that axis about the femur's length: the tibia then turns, in Plug-in Gait's own femur frame, about
another axis, its knee varus-valgus swings in step with flexion (cross-talk), and its knee centre leaves the
line the knee turns about.  A gait lab knows the symptom; this finds it from the bones the file carries
(``LFEO``/``LFEA``/``LFEL``/``LFEP``, ``LTIO``...): the axis the tibia frame turns about in the femur frame does
not depend on how the tibia frame itself is twisted, so the check needs no marker and no model.

Only the knee: Plug-in Gait builds the foot frame from the tibia's flexion axis and the radius frame from the
humerus's, so their joints turn about Plug-in Gait's axes by construction.  pig_walk's knees are 34 and 43 deg
off (docs/benchmarks.md, "Plug-in Gait's knee axes").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..io.motion import Motion
from ..io.trial import Trial
from ..model.model import Model, Parameters

#: The knee must turn through this much (5th to 95th percentile about its axis) for the axis to be told: a walk's
#: knee turns 55-65 deg, a static not at all.
MIN_TURN = math.radians(30.0)
#: Plug-in Gait's knee axis further than this from the axis its tibia turns about is called misaligned: careful
#: marker placement keeps it within 5-10 deg; a thigh wand turned on the thigh puts it 20-40 deg off.
MISALIGNED = math.radians(15.0)
KNEES = (("knee_l", "L"), ("knee_r", "R"))


@dataclass(frozen=True)
class KneeAxisCheck:
    """One knee of one trial carrying Plug-in Gait's femur and tibia bones.  Angles in rad, distances in m."""

    joint: str  # the model's knee (knee_l, knee_r), named as in models/human.urdf
    trial: int  # index of the trial in the calibration
    source: str  # the trial's file, or 'trial N'
    frames: int  # frames where both bones are seen
    turn: float  # how far the tibia turns about the axis found (5th to 95th percentile)
    pig: float  # Plug-in Gait's knee axis (its femur's lateral axis) from that axis
    varus: float | None  # Plug-in Gait's knee varus-valgus angle's range (5th to 95th percentile), if the file has it
    ours: float | None  # the calibrated knee axis from that axis (None: the model has no such hinge)
    centre: float | None  # Plug-in Gait's knee centre from the calibrated knee's hinge line (median over the frames)

    @property
    def misaligned(self) -> bool:
        return self.pig > MISALIGNED

    def text(self) -> str:
        """e.g. 'its knee_l axis is 34 deg from the axis its tibia turns about (varus-valgus spanning 42 deg),
        calibrate's 9 deg; its knee centre 64 mm from calibrate's knee_l axis'."""
        out = f"its {self.joint} axis is {math.degrees(self.pig):.0f} deg from the axis its tibia turns about"
        if self.varus is not None:
            out += f" (varus-valgus spanning {math.degrees(self.varus):.0f} deg)"
        if self.ours is not None and self.centre is not None:
            out += (f", calibrate's {math.degrees(self.ours):.0f} deg; its knee centre {1e3 * self.centre:.0f} mm "
                    f"from calibrate's {self.joint} axis")
        return out

    def to_json(self) -> dict:
        def deg(v: float | None) -> float | None:
            return None if v is None else math.degrees(v)

        return {"joint": self.joint, "trial": self.source, "frames": self.frames, "turn_deg": deg(self.turn),
                "plugin_gait_axis_deg": deg(self.pig), "varus_valgus_range_deg": deg(self.varus),
                "our_axis_deg": deg(self.ours), "plugin_gait_centre_from_our_axis_mm":
                    None if self.centre is None else 1e3 * self.centre, "misaligned": self.misaligned}


def bone_frames(trial: Trial, bone: str) -> np.ndarray | None:
    """(n_frames, 3, 3) rotations of a Plug-in Gait bone (``LFE``, ``RTI``...) from its points O, A, L, P in the
    trial's model outputs: columns anterior, lateral (L, made normal to the length) and proximal (O to P); NaN
    where a point is not seen; None when the file lacks one of the four."""
    pts = [trial.model_outputs.get(bone + k) for k in "OALP"]
    if any(p is None or trial.output_kinds.get(bone + k) != "point" for p, k in zip(pts, "OALP", strict=True)):
        return None
    o, _, lat, prox = (np.asarray(p, dtype=float) for p in pts)
    z = prox - o
    y = lat - o
    with np.errstate(invalid="ignore", divide="ignore"):
        z = z / np.linalg.norm(z, axis=1, keepdims=True)
        y = y - np.sum(y * z, axis=1, keepdims=True) * z
        y = y / np.linalg.norm(y, axis=1, keepdims=True)
    return np.stack([np.cross(y, z), y, z], axis=2)


def turn_axis(parent: np.ndarray, child: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The axis (unit, in the parent's frame) about which `child` turns relative to `parent` over the frames
    ((n, 3, 3) world rotations each, finite), and how far (5th to 95th percentile): the principal direction of the
    relative rotations taken from their mean, exact for a hinge and unchanged by a constant twist of the child's
    frame.  None for fewer than 10 frames."""
    from ..model.rotations import matrix_quats, quat_inverse, quat_multiply, quat_rotvecs

    if len(parent) < 10:
        return None
    # In numpy, as scipy's Rotation computes them (its import took a quarter of a second of each such run): the
    # relative rotations, their mean (the chordal L2 mean: the principal eigenvector of the quaternions' scatter, as
    # Rotation.mean), and each one's rotation vector from it.
    rel = matrix_quats(np.einsum("fji,fjk->fik", parent, child))
    mean = np.linalg.eigh(rel.T @ rel)[1][:, -1]
    v = quat_rotvecs(quat_multiply(rel, quat_inverse(mean)))
    _, _, vt = np.linalg.svd(v - v.mean(axis=0), full_matrices=False)
    axis = vt[0]
    s = v @ axis
    return axis, float(np.percentile(s, 95) - np.percentile(s, 5))


def plugin_gait_knees(trial: Trial, index: int = 0) -> list[tuple[KneeAxisCheck, np.ndarray, np.ndarray, np.ndarray]]:
    """KneeAxisCheck of each knee whose Plug-in Gait femur and tibia bones the trial carries, seen in enough frames
    and turning through MIN_TURN, from the file alone (no calibrated knee: `ours` and `centre` None), each with the
    frames used (bool mask), the axis found in the femur bone's frame and the femur bone's rotations (bone_frames).
    `index`: the trial's in a calibration."""
    out = []
    for joint, side in KNEES:
        femur, tibia = bone_frames(trial, side + "FE"), bone_frames(trial, side + "TI")
        if femur is None or tibia is None:
            continue
        ok = np.all(np.isfinite(femur), axis=(1, 2)) & np.all(np.isfinite(tibia), axis=(1, 2))
        found = turn_axis(femur[ok], tibia[ok])
        if found is None or found[1] < MIN_TURN:
            continue
        axis, turn = found
        pig = math.acos(min(1.0, abs(float(axis[1]))))
        check = KneeAxisCheck(joint, index, trial.source or f"trial {index + 1}", int(ok.sum()), turn, pig,
                              _range(trial, side + "KneeAngles", 1, ok), None, None)
        out.append((check, ok, axis, femur))
    return out


def knee_axis_checks(model: Model, params: Parameters, trials: Sequence[Trial],
                     motions: Sequence[Motion]) -> tuple[KneeAxisCheck, ...]:
    """plugin_gait_knees of every trial, each compared with the calibrated knee (a hinge named knee_l / knee_r) where
    the model has it: the calibrated axis's angle from the axis Plug-in Gait's tibia turns about, and Plug-in
    Gait's knee centre's distance from the calibrated knee's line."""
    out = []
    for i, (trial, motion) in enumerate(zip(trials, motions, strict=True)):
        lines: dict | None = None  # the model's hinge lines over this trial, formed when first needed
        for check, ok, axis, femur in plugin_gait_knees(trial, i):
            joint = check.joint
            if not any(j.name == joint and j.kind == "hinge" for j in model.joints):
                out.append(check)
                continue
            if lines is None:
                from ..model.hinges import hinge_lines_world

                lines = hinge_lines_world(model, params, motion)
            at, a = lines[joint]
            local = np.einsum("fji,fj->fi", femur[ok], a[ok])  # our axis in Plug-in Gait's femur frame
            mean = np.median(local * np.sign(local @ axis)[:, None], axis=0)
            ours = math.acos(min(1.0, abs(float(axis @ mean)) / float(np.linalg.norm(mean))))
            kjc = np.asarray(trial.model_outputs[dict(KNEES)[joint] + "FEO"], dtype=float)[ok] - at[ok]
            across = kjc - np.sum(kjc * a[ok], axis=1, keepdims=True) * a[ok]
            out.append(replace(check, ours=ours, centre=float(np.median(np.linalg.norm(across, axis=1)))))
    return tuple(out)


def _range(trial: Trial, name: str, component: int, ok: np.ndarray) -> float | None:
    """The 5th to 95th percentile range (rad) of one component of an angle output over the frames `ok`; None when
    the file lacks it or does not give it in radians."""
    if trial.output_kinds.get(name) != "angle" or trial.output_units.get(name) != "rad":
        return None
    v = np.asarray(trial.model_outputs[name], dtype=float)[ok, component]
    v = v[np.isfinite(v)]
    return float(np.percentile(v, 95) - np.percentile(v, 5)) if v.size >= 10 else None
