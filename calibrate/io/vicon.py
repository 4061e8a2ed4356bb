"""Vicon model outputs carried in trial files: Plug-in Gait's bones, joint centres and kinematic/kinetic quantities,
recognised by name (is_model_output) and Plug-in Gait's own joint centres (plugin_gait_centres)."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np

from calibrate.io.trial import Trial

#: SI unit of each kind of model output (what :attr:`Trial.model_outputs` holds when the file
#: gives a unit it knows; see :attr:`Trial.output_units`).
OUTPUT_SI_UNITS: dict[str, str] = {"point": "m", "angle": "rad", "force": "N", "moment": "N m", "power": "W"}


#: Model-output units that are converted to SI on reading: unit (lower case, no spaces or dots) -> factor.
OUTPUT_UNIT_FACTORS: dict[str, dict[str, float]] = {
    "angle": {"deg": np.pi / 180.0, "degree": np.pi / 180.0, "degrees": np.pi / 180.0, "rad": 1.0, "radians": 1.0},
    "force": {"n": 1.0, "kn": 1e3},
    "moment": {"nmm": 1e-3, "nm": 1.0, "knm": 1e3},
    "power": {"w": 1.0, "kw": 1e3, "mw": 1e-3},
    "point": {"mm": 1e-3, "cm": 1e-2, "m": 1.0},
}


#: Plug-in Gait "bones": segment codes whose origin (O), anterior (A), lateral (L) and proximal (P)
#: points Plug-in Gait writes (Vicon Nexus help, "Plug-in Gait bones"); side-less codes first.
PIG_BONES_MIDLINE = ("PEL", "HED", "TRX", "CSP", "SAC")


PIG_BONES_SIDED = ("FE", "TI", "FO", "TO", "CL", "HU", "RA", "HN")


_PIG_BONE = re.compile(
    r"^(?:(?:" + "|".join(PIG_BONES_MIDLINE) + r")|[LR](?:" + "|".join(PIG_BONES_SIDED) + r"))[OALP]$"
)


#: Joint-centre and other point outputs of Plug-in Gait and its clones (pyCGM, pyCGM2, biomechZoo).
_PIG_CENTRE = re.compile(
    r"^(?:[LR](?:HJC|KJC|AJC|SJC|EJC|WJC|FJC|HipJC|KneeJC|AnkleJC|ShoulderJC|ElbowJC|WristJC)"
    r"|CentreOfMass|CentreOfMassFloor|CenterOfMass|CenterOfMassFloor|COM|COMFloor)$"
)


#: Names of Plug-in Gait's angle, force, moment and power outputs: LKneeAngles, RHipMoment, LNormalisedGRF...
_PIG_QUANTITY = re.compile(
    r"^[LR]?[A-Za-z]+(?:Angles?|Force|GRF|Moment|Power)$"
)


_QUANTITY_KIND = (("Angle", "angle"), ("Force", "force"), ("GRF", "force"), ("Moment", "moment"), ("Power", "power"))


def is_model_output(label: str) -> str | None:
    """The kind of model output a label names by Plug-in Gait's conventions, or None for a marker.

    ``'point'`` for the Plug-in Gait bones (``<SEG>O/A/L/P``: ``PELO``, ``LFEO``, ``HEDA``, ``RHNP``...),
    joint centres (``LHJC``, ``RKJC``, ``LKneeJC``...) and the centre of mass (``CentreOfMass``,
    ``CentreOfMassFloor``); ``'angle'``, ``'force'``, ``'moment'`` or ``'power'`` for names such as
    ``LKneeAngles``, ``RNormalisedGRF``, ``LHipMoment``, ``RAnklePower``.  A subject prefix
    (``Sub01:LFEO``) is ignored.
    """
    name = str(label).strip().split(":")[-1].strip()
    if _PIG_BONE.match(name) or _PIG_CENTRE.match(name):
        return "point"
    if _PIG_QUANTITY.match(name):
        return next(kind for word, kind in _QUANTITY_KIND if word in name)
    return None


#: Plug-in Gait outputs at (or, for the hip, next to) the lower-limb joint centres, per joint of
#: ``models/human.urdf``: explicit joint-centre outputs first, then the bone points.
PIG_CENTRE_LABELS: dict[str, tuple[str, ...]] = {
    "hip_l": ("LHJC", "LHipJC", "LFEP"),
    "hip_r": ("RHJC", "RHipJC", "RFEP"),
    "knee_l": ("LKJC", "LKneeJC", "LFEO"),
    "knee_r": ("RKJC", "RKneeJC", "RFEO"),
    "ankle_l": ("LAJC", "LAnkleJC", "LTIO"),
    "ankle_r": ("RAJC", "RAnkleJC", "RTIO"),
}


#: Segment-axes points: the arms' lengths' SD over the frames (or their spread within a frame) relative to their mean,
#: and the largest |cos| between two arms, below which four labels <stem>O/A/L/P are a modelling program's, not markers.
AXES_EXACT = 1e-4


def segment_axes(labels: tuple[str, ...] | list[str], markers: np.ndarray) -> list[str]:
    """The labels of segment-axes points a modelling program wrote as trajectories under names other than Plug-in
    Gait's bones (:func:`is_model_output`): four labels ``<stem>O``, ``A``, ``L``, ``P`` whose A, L and P lie from O
    along three orthogonal directions in every frame seen, at fixed distances or at one distance that changes with the
    frame, to :data:`AXES_EXACT` (a children's hospital's ``Pelvis_GOMO`` ... ``Pelvis_GOMP`` and ``LFemFunO``...:
    100.000 mm arms; a lab's ``LFE_MO`` ... ``LFE_MP``: three arms as long as its femur, which its markers give
    anew in each frame); and, beside them, any four labels so named that the trial never shows (the same lab's
    ``HED_MO`` ... ``HED_MP``, the head it did not model).  No marker set is that exact: skin and the cameras move
    real markers by 0.1 mm and more.  As markers they are exactly rigid on a segment of the lab's model, which
    rigidity then reads as the trial's noise level, and they sit 100 mm off the body where that model puts its
    segments (the children's hospital's walk: 99 labels left out, 7.60 mm RMS; read as outputs, 9 and 5.47 mm).
    `markers` (F, N, 3), NaN in gaps."""
    index = {label: i for i, label in enumerate(labels)}
    markers = np.asarray(markers, dtype=float)
    out: list[str] = []
    empty: list[list[str]] = []
    for label in labels:
        stem = label[:-1]
        if label[-1:].upper() != "O" or not stem:
            continue
        quad = [next((stem + c for c in (s, s.lower()) if stem + c in index), None) for s in "OALP"]
        if None in quad:
            continue
        X = markers[:, [index[q] for q in quad], :]
        if not np.isfinite(X).any():
            empty.append(quad)
        X = X[np.isfinite(X).all(axis=(1, 2))]
        if len(X) < 3:
            continue
        arms = X[:, 1:] - X[:, :1]
        length = np.linalg.norm(arms, axis=2)
        fixed = np.all(length.std(0) <= AXES_EXACT * length.mean(0))
        equal = np.all(np.ptp(length, axis=1) <= AXES_EXACT * length.mean(1))
        if not (length.min() > 0 and (fixed or equal)):
            continue
        unit = arms / length[..., None]
        cos = np.abs(np.einsum("fij,fkj->fik", unit, unit)[:, [0, 0, 1], [1, 2, 2]])
        if cos.max() <= AXES_EXACT:
            out.extend(quad)
    return out + [label for quad in empty for label in quad] if out else out


def axes_as_outputs(trial: Trial, axes: list[str]) -> Trial:
    """`trial` with `axes`, its segment-axes points (:func:`segment_axes`), moved from its markers to its model outputs
    (points, metres), as a file that lists them among its outputs has them; the trial itself when there are none."""
    if not axes:
        return trial
    drop = set(axes)
    keep = [label for label in trial.labels if label not in drop]
    outputs = {**trial.model_outputs, **{label: trial.marker(label) for label in axes}}
    return replace(trial.select(keep), model_outputs=outputs,
                   output_kinds={**trial.output_kinds, **dict.fromkeys(axes, "point")},
                   output_units={**trial.output_units, **dict.fromkeys(axes, "m")})


def plugin_gait_centres(trial: Trial) -> dict[str, np.ndarray]:
    """Plug-in Gait's own hip, knee and ankle joint centres from a trial's model outputs.

    Returns ``{'hip_l': (n_frames, 3), ..., 'ankle_r': ...}`` in metres (lab frame, NaN where
    the file has a gap), keyed by the joint names of ``models/human.urdf``; a joint is absent when
    the file carries none of its outputs.  Explicit joint-centre points (``LHJC``, ``LKJC``,
    ``LAJC``, and pyCGM's ``LHipJC``...) are used when present, else the Plug-in Gait bones:

    - knee: the femur origin ``LFEO``/``RFEO`` (Plug-in Gait's knee joint centre, KJC);
    - ankle: the tibia origin ``LTIO``/``RTIO`` (its ankle joint centre, AJC);
    - hip: the femur proximal point ``LFEP``/``RFEP`` (its hip joint centre, HJC, from the Davis
      regression; Plug-in Gait writes no hip-centre point of its own); the pelvis bone origin
      ``PELO`` is the midpoint of the two.

    Checked on the pyCGM sample subject (docs/calibration.md, "Vicon model outputs"): ``LFEO``
    is KneeWidth/2 + marker radius from ``LKNE`` in every frame, ``LTIO`` AnkleWidth/2 + marker
    radius from ``LANK`` (Plug-in Gait's chord function), and ``LFEP``, ``RFEP`` sit where the
    Davis regression with the file's own subject measurements puts the hip centres in the pelvis.
    """
    found: dict[str, np.ndarray] = {}
    for joint, names in PIG_CENTRE_LABELS.items():
        for name in names:
            if name in trial.model_outputs and trial.output_kinds.get(name) == "point":
                found[joint] = np.array(trial.model_outputs[name], dtype=float)
                break
    return found


def output_factor(kind: str, unit: str) -> tuple[float, str]:
    """Factor from a model output's file unit to SI, and the unit of the result (the file's when unknown)."""
    key = re.sub(r"[\s.·*]", "", unit).lower()
    factors = OUTPUT_UNIT_FACTORS.get(kind, {})
    if key in factors:
        return factors[key], OUTPUT_SI_UNITS[kind]
    if not key and kind == "angle":  # Vicon writes angles in degrees
        return factors["deg"], OUTPUT_SI_UNITS[kind]
    return 1.0, unit.strip() or "file units"
