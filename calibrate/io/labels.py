"""Trial marker labels to model marker labels: a marker map file and built-in aliases.

:func:`map_labels` renames a trial's markers to the model's labels and reports, for every
trial label, what it became and how:

- ``exact``: the trial label is a model label;
- ``map``: the marker map (``--markers map.toml``, :func:`load_marker_map`) lists it under a model label;
- ``alias``: a common spelling of a model label (the table below);
- ``unknown``: none of these; the label is kept as it is, so that a later stage (placing
  unknown markers on segments by rigidity) can still use the marker.

Each trial label gets its best match in that order.  When several trial labels would take the
same model label (``R.Knee`` and ``R.Knee.Lat`` both present) one is kept, by rank: exact,
then map, then alias; within the map, the order of the entry's list; within the aliases, the
order of the alias table; at a tie, the first in the trial, with a :class:`LabelConflictWarning`.
The others keep their own labels (``unknown``) and the mapping says which label was kept.

Subject prefixes: the trial readers remove a prefix shared by all labels (``Sub01:RASI``).  A
label that still has one (several subjects, or a skeleton and rigid bodies in one OptiTrack
file) is matched by its whole text first, then by its name after the prefix; a match after the
prefix ranks below every match of a whole label.

Aliases. Labels are compared after normalisation: lower case, the separators ``.``, ``_``, ``-`` and spaces removed,
camel case split (``RightKnee`` = ``Right Knee``, ``LKneeOut`` = ``L Knee Out``). A side is read from a first or last
word ``R``/``L``/``Right``/``Left`` (``R.Knee``, ``knee_r``, ``RightKnee``), from one between words (``knee_l_lat``;
OptiTrack's and Qualisys' ``WaistLFront``), or from the first letter (``RKNEE``); OpenSim's midline prefix ``V.``
(``V.Sacral``) and the suffix ``_study`` of OpenCap's marker augmenter (``r.ASIS_study``, ``r_knee_study``,
``C7_study``; its ``r_lelbow``, ``r_lwrist`` and ``r_mwrist`` the lateral elbow and the radial and ulnar wrist) are
dropped. The rest is looked up below (most specific first). An alias only maps to a label the model has: the Plug-in
Gait label, else the model label that reads as the same one (Rajagopal2016's ``L.Knee`` for a trial's ``L_Knee_Lat``:
both read as ``LKNE``; the lowest-ranked spelling where several do, ``L.Ankle`` before ``LLMAL``). Our Plug-in Gait
model has no ``SACR``, nor any label that reads so, so ``V.Sacral`` stays unknown there.

============  =====================================================================================
model label   alias names, after the side (R or L) and normalisation
============  =====================================================================================
xASI          asi, asis, antsupiliacspine, anteriorsuperioriliacspine, ias, waistfront, fwt, frontwaist, eias, eas
xPSI          psi, psis, postsupiliacspine, posteriorsuperioriliacspine, ips, backasis, bwt, backwaist, eips, eps
xTHI          thi, thigh, thighwand, bar1
xKNE          kne, kneelat, kneelateral, latknee, lateralknee, knee1, knee, latepicondyle, lateralepicondyle,
              fle, lfe, le, latfemepicondyle, lateralfemoralepicondyle, femurlateralepicondyle, lek,
              lfc, latfemcondyle, lateralfemoralcondyle, kneeout, lepi, latepi, cl
xTIB          tib, tibia, shank, tibwand, shankwand, bar2
xANK          ank, anklelat, anklelateral, latankle, lateralankle, latmalleolus, lateralmalleolus,
              malleoluslat, mall, ankle, lm, fal, lmal, latmal, ankleout, ml
xHEE          hee, heel, calc, calcaneus, ca, fcc, cal, heelback
xTOE          toe, mt2, mth2, metatarsal2, toetip, fm2, sm, mh2
xSHO          sho, shoulder, acromion, acromium, acr, ac, caj, acromioclavicular, should, sh
xUPA          upa, upperarm, arm, humerus, bicep, biceps
xELB          elb, elbowlat, elbowlateral, latelbow, lateralelbow, elbow, el, hle, lhe,
              lateralhumeralepicondyle, humerallateralepicondyle, humeruslateralepicondyle, lee, lel, lelbow,
              elbowout
xFRM          frm, forearm
xWRA          wra, wrista, wristlat, wristlateral, wristradial, radialwrist, radialstyloid, radius,
              rs, rsp, radialstyloidprocess, lw, faradius, lwrist, wristradius
xWRB          wrb, wristb, wristmed, wristmedial, wristulnar, ulnarwrist, ulnarstyloid, ulna,
              us, usp, ulnarstyloidprocess, mw, faulna, mwrist, wristulna
xFIN          fin, finger, mcp2, mc2, hand, hm2
xFHD          fhd, fronthead, headfront, forehead, temple, hdf
xBHD          bhd, backhead, headback, rearhead, headrear, hdb
xBAK          bak, back, scapula, scap
C7            c7, vertebrac7, cv7, backtop
T10           t10, th10, vertebrat10, tv10
CLAV          clav, clavicle, jugularnotch, jugular, sternalnotch, suprasternalnotch, ij, sjn, snj, manubrium,
              man
STRN          strn, sternum, xiphoid, xiphoidprocess, px, sxs
SACR          sacr, sacrum, sacral
============  =====================================================================================

Anatomical landmark names (ISB: Wu et al. 2002, 2005; CAST: Cappozzo et al. 1995; Van Sint
Jan's landmark atlas as Dumas' models spell it: ``RFLE``, ``RFAL``...) map to a Plug-in Gait
marker only where the landmark is the point the marker is put on (docs/calibration.md, labels):
IAS/IPS the iliac spines; LE, FLE, LFE the lateral femoral epicondyle (KNE); LM, FAL the
lateral malleolus (ANK); CA, FCC the calcaneus (HEE); FM2, SM the second metatarsal head (TOE);
AC, CAJ the acromio-clavicular joint (SHO); EL, HLE, LHE the lateral humeral epicondyle (ELB);
RS, RSP and US, USP the radial and ulnar styloid (WRA, WRB); HM2 the second metacarpal head
(FIN); IJ, SJN the jugular notch (CLAV); PX, SXS the xiphoid (STRN); CV7, TV10 the spinous
processes; Motek's Human Body Model spells the knee's and the elbow's lateral epicondyles LEK and LEE, the
wrist's lateral (radial) and medial (ulnar) sides LW and MW; the Rajagopal2016 copy in ../shared spells the
lateral femoral condyle LFC, the lateral elbow LEL and the forearm's styloids FAradius and FAulna, and
AddBiomechanics' Expert1 trials the styloids R_wrist_radius and R_wrist_ulna; BTS's Davis
protocol (``r knee 1``, ``r mall``, ``r bar 1``, ``r bar 2``) the lateral femoral epicondyle and malleolus and its
thigh and shank wands, where Plug-in Gait has its own (its ``r met``, the fifth metatarsal head, is not TOE's second),
before a plain ``r knee`` or ``r ankle`` (c3d.org's sample28, a BTS file, holds both: those are its joint centres,
62 and 47 mm from the epicondyle and the malleolus).
OptiTrack Motive's and Qualisys' animation and sports marker sets spell the ASIS ``WaistLFront`` (Motive's
documentation: on the anterior iliac spine) and the lateral knee, ankle and elbow and the heel ``LKneeOut``,
``LAnkleOut``, ``LElbowOut``, ``LHeelBack``, and C7 ``BackTop`` (on the spine right below the neck; ``LThigh``
reads as the thigh marker); their ``WaistLBack`` (10 cm
above the hip joint, not the posterior spine), ``LShin`` and the rest stay unknown, placed on their segments like any
new label.  The CMU motion-capture database (Vicon's animation set) spells the ASIS and PSIS front and back
waist, ``LFWT`` and ``LBWT`` (on its subject 01 239 and 100 mm apart, 220 mm front to back: the iliac spines'
figures); its ``LSHN``, ``LMT5`` and ``RBAC`` stay unknown.
French clinical sets spell the iliac spines EIAS / EIPS or EAS / EPS (épine iliaque antéro- / postéro-supérieure), the
lateral femoral condyle CL and the lateral malleolus ML (condyle, malléole latéral·e), their medial twins CM and MM
(BTKData's ``Res16bits``: ``REAS``, ``RCL``, ``RML``, ``RCM``, ``RMM``, described ``R.EAS``...).
Medial landmarks (FME, MM, EM...) have no Plug-in Gait marker and stay unknown.
A lateral epicondyle that names no bone (``LateralEpicondyleL``, ``LLEPI``) is the knee's, unless the trial's other
labels show that side's arm and not its leg, or no leg at all (kineticstoolkit's wheelchair trials: ``AcromionL``,
``HandL``), or that side's knee under another label beside its arm's markers: then it is the elbow's
(:func:`elbow_sides`).

So ``R.ASIS``, ``RASIS``, ``R_ASIS``, ``r_asis``, ``RightASIS``, ``R.ASI`` and ``ASIS_R`` all become
``RASI``; ``R.Knee.Lat`` and ``R.Knee`` become ``RKNE`` (``R.Knee.Lat`` kept when both are there);
``R.Knee.Med``, ``R.Ankle.Med`` and the thigh/shank cluster markers of OpenSim's gait2392 set
(``R.Thigh.Upper``...) have no Plug-in Gait counterpart and stay unknown.

The marker map file is TOML, one line per model label, its trial labels in order of preference::

    RASI = ["R.ASIS", "RASIS"]
    RKNE = ["R.Knee.Lat", "R.Knee"]
    C7 = "Neck"                 # a single label may be given as a string

Map entries match trial labels exactly (case and separators count).
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..errors import CalibrateError
from .trial import Trial

#: an unlabelled trajectory's label (Vicon Nexus: '*115'; OptiTrack Motive: 'Unlabeled 1000')
UNLABELLED = re.compile(r"\*\d+|Unlabeled \d+")

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "HOWS",
    "LabelConflictWarning",
    "LabelMapping",
    "LabelMatch",
    "MarkerMap",
    "alias_for",
    "load_marker_map",
    "map_labels",
]

#: A subject prefix whose labels match this many of the model's markers or more is a subject of the trial
#: (map_labels refuses a trial with two: which to calibrate is the user's choice, Trial.of_subject).
SUBJECT_MARKERS = 3

#: How a trial label was matched, in the order the mapping counts them (the marker map ranks first, then the label
#: itself, the built-in aliases, the file's description of the label: _RANK).
HOWS = ("exact", "map", "alias", "description", "unknown")

#: Plug-in Gait marker codes that come in left and right (label = side letter + code), with alias
#: names after the side and normalisation, most specific first.
SIDE_ALIASES: dict[str, tuple[str, ...]] = {
    "ASI": ("asi", "asis", "antsupiliacspine", "anteriorsuperioriliacspine", "ias", "waistfront", "fwt", "frontwaist",
            "eias", "eas"),
    "PSI": ("psi", "psis", "postsupiliacspine", "posteriorsuperioriliacspine", "ips", "backasis", "bwt", "backwaist",
            "eips", "eps"),
    "THI": ("thi", "thigh", "thighwand", "bar1"),
    "KNE": (
        "kne", "kneelat", "kneelateral", "latknee", "lateralknee", "knee1", "knee", "latepicondyle",
        "lateralepicondyle", "fle", "lfe", "le", "latfemepicondyle", "lateralfemoralepicondyle",
        "femurlateralepicondyle", "lek", "lfc", "latfemcondyle", "lateralfemoralcondyle", "kneeout", "lepi",
        "latepi", "cl",
    ),
    "TIB": ("tib", "tibia", "shank", "tibwand", "shankwand", "bar2"),
    "ANK": (
        "ank", "anklelat", "anklelateral", "latankle", "lateralankle", "latmalleolus", "lateralmalleolus",
        "malleoluslat", "mall", "ankle", "lm", "fal", "lmal", "latmal", "ankleout", "ml",
    ),
    "HEE": ("hee", "heel", "calc", "calcaneus", "ca", "fcc", "cal", "heelback"),
    "TOE": ("toe", "mt2", "mth2", "metatarsal2", "toetip", "fm2", "sm", "mh2"),
    "SHO": ("sho", "shoulder", "acromion", "acromium", "acr", "ac", "caj", "acromioclavicular", "should", "sh"),
    "UPA": ("upa", "upperarm", "arm", "humerus", "bicep", "biceps"),
    "ELB": (
        "elb", "elbowlat", "elbowlateral", "latelbow", "lateralelbow", "elbow", "el", "hle", "lhe",
        "lateralhumeralepicondyle", "humerallateralepicondyle", "humeruslateralepicondyle", "lee", "lel", "lelbow",
        "elbowout",
    ),
    "FRM": ("frm", "forearm"),
    "WRA": (
        "wra", "wrista", "wristlat", "wristlateral", "wristradial", "radialwrist", "radialstyloid", "radius",
        "rs", "rsp", "radialstyloidprocess", "lw", "faradius", "lwrist", "wristradius",
    ),
    "WRB": (
        "wrb", "wristb", "wristmed", "wristmedial", "wristulnar", "ulnarwrist", "ulnarstyloid", "ulna",
        "us", "usp", "ulnarstyloidprocess", "mw", "faulna", "mwrist", "wristulna",
    ),
    "FIN": ("fin", "finger", "mcp2", "mc2", "hand", "hm2"),
    "FHD": ("fhd", "fronthead", "headfront", "forehead", "temple", "hdf"),
    "BHD": ("bhd", "backhead", "headback", "rearhead", "headrear", "hdb"),
    "BAK": ("bak", "back", "scapula", "scap"),
}

#: Midline Plug-in Gait markers, with alias names after normalisation, most specific first.
MIDLINE_ALIASES: dict[str, tuple[str, ...]] = {
    "C7": ("c7", "vertebrac7", "cv7", "backtop"),
    "T10": ("t10", "th10", "vertebrat10", "tv10"),
    "CLAV": ("clav", "clavicle", "jugularnotch", "jugular", "sternalnotch", "suprasternalnotch", "ij", "sjn", "snj",
             "manubrium", "man"),
    "STRN": ("strn", "sternum", "xiphoid", "xiphoidprocess", "px", "sxs"),
    "SACR": ("sacr", "sacrum", "sacral"),
}

#: Lateral-epicondyle spellings that name no bone: the femur's (KNE) in a leg's marker set, the humerus's (ELB) in an
#: arm's (kineticstoolkit's wheelchair trials: ``BodyL:LateralEpicondyleL`` beside ``AcromionL`` and ``HandL``, no leg
#: marker).  Read as the knee's unless the trial's other labels say the elbow's (:func:`elbow_sides`).
EPICONDYLE = ("latepicondyle", "lateralepicondyle", "lepi", "latepi")
#: The codes that tell a side's leg (below the hip) and arm apart, for :func:`elbow_sides`.
LEG_CODES = ("THI", "KNE", "TIB", "ANK", "HEE", "TOE")
ARM_CODES = ("SHO", "UPA", "ELB", "FRM", "WRA", "WRB", "FIN")

_SIDE_WORDS = {"r": "R", "right": "R", "l": "L", "left": "L"}
_SIDE_LOOKUP = {name: (code, rank) for code, names in SIDE_ALIASES.items() for rank, name in enumerate(names)}
_MIDLINE_LOOKUP = {name: (label, rank) for label, names in MIDLINE_ALIASES.items() for rank, name in enumerate(names)}
_SEPARATORS = re.compile(r"[\s._\-]+")
_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])")  # RightKnee, WaistLFront, LKneeOut
_RANK = {"map": 0, "exact": 1, "alias": 2, "description": 3}


class LabelConflictWarning(UserWarning):
    """Several trial labels matched one model label equally well; the first in the trial was kept."""


class MarkerMapWarning(UserWarning):
    """A marker map's ``[segments]`` lists labels no trial shows (a misspelling, or a map for other sessions)."""


class MarkerMap(dict[str, list[str]]):
    """A marker map: model label -> trial labels in order of preference; ``source`` names its file;
    ``segments``: segment -> the trial labels the model does not have that ride on it (the file's
    ``[segments]`` table: a lab's cluster or wand markers, placed there without the hosts' tests)."""

    source: str | None = None
    segments: dict[str, list[str]]

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.segments = {}


#: The marker map's table of new labels by segment (``[segments]`` in the TOML file; the same key in a mapping).
SEGMENTS = "segments"


def declared_segments(marker_map: Mapping | None, model=None) -> dict[str, str]:
    """Trial label -> segment, as `marker_map`'s ``[segments]`` table declares them (a MarkerMap's ``segments``, or a
    mapping's ``"segments"`` entry: segment -> labels); {} where it declares none.  Checked as load_marker_map checks
    the file's table, and each segment against `model`'s (calibrate.model.Model), where given (CalibrateError, one
    line)."""
    if marker_map is None:
        return {}
    table = getattr(marker_map, "segments", None)
    if table is None:
        table = marker_map.get(SEGMENTS) if isinstance(marker_map.get(SEGMENTS), Mapping) else {}
    source = getattr(marker_map, "source", None)
    declared = _segment_table(table, source)
    if model is not None:
        segments = [s.name for s in model.segments]
        if bad := [seg for seg in declared.values() if seg not in segments]:
            raise _map_error(source, f"[segments] names '{bad[0]}', which is not a segment of {model.path.name}",
                             f"use one of {', '.join(segments[:8])}, ... (see calibrate inspect)")
    return declared


def _segment_table(table: Mapping, where: str | None) -> dict[str, str]:
    """Trial label -> segment from a ``[segments]`` table (segment -> trial labels, or one label)."""
    out: dict[str, str] = {}
    for segment, value in table.items():
        example = f'write it as {segment} = ["LTH1", "LTH2"] (segment = list of trial labels)'
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise _map_error(where, f"[segments] {segment} = {value!r} is not a list of trial labels", example)
        labels = [v.strip() for v in value]
        if not labels or not all(labels):
            raise _map_error(where, f"[segments] {segment} lists no trial label or an empty one",
                             "list the labels of the markers that ride on it")
        for label in labels:
            if out.get(label, segment) != segment:
                raise _map_error(where, f"[segments]: trial label {label!r} is listed under both {out[label]} and "
                                        f"{segment}", "list it under the one segment it rides on")
            out[label] = str(segment)
    return out


def _words(label: str) -> list[str]:
    """Lower-case words of a label: split at separators and camel-case boundaries."""
    return [word.lower() for part in _SEPARATORS.split(label) for word in _CAMEL.split(part) if word]


def _readings(label: str) -> list[tuple[str | None, str]]:
    """The (side or None, name) readings of a label, in order of trust (the module docstring's rules)."""
    words = _words(label)
    if _augmented(label):  # OpenCap's marker augmenter: r.ASIS_study, r_knee_study, C7_study
        words = words[:-1]
    if not words:
        return []
    joined = "".join(words)
    readings: list[tuple[str | None, str]] = []
    if len(words) > 1 and words[0] in _SIDE_WORDS:
        readings.append((_SIDE_WORDS[words[0]], "".join(words[1:])))
    if len(words) > 1 and words[-1] in _SIDE_WORDS:
        readings.append((_SIDE_WORDS[words[-1]], "".join(words[:-1])))
    middle = [k for k in range(1, len(words) - 1) if words[k] in _SIDE_WORDS]
    if len(middle) == 1:  # the side between words: OptiTrack's and Qualisys' WaistLFront, knee_l_lat
        k = middle[0]
        readings.append((_SIDE_WORDS[words[k]], "".join(words[:k] + words[k + 1:])))
    for word in ("right", "left"):
        if joined.startswith(word) and len(joined) > len(word):
            readings.append((_SIDE_WORDS[word], joined[len(word) :]))
    if joined[0] in "rl" and len(joined) > 1:
        readings.append((joined[0].upper(), joined[1:]))
    if len(words) > 1 and words[0] == "v":  # OpenSim's midline prefix: V.Sacral
        readings.append((None, "".join(words[1:])))
    readings.append((None, joined))
    return readings


def _augmented(label: str) -> bool:
    """Whether `label` is a marker of OpenCap's marker augmenter (``r_knee_study``)."""
    words = _words(label)
    return len(words) > 1 and words[-1] == "study"


def _codes(label: str, elbows: frozenset[str] = frozenset()) -> list[tuple[str, int]]:
    """The Plug-in Gait labels a label reads as (side + code, or a midline label) with their alias ranks, in the
    order of its readings; a bare lateral epicondyle (EPICONDYLE) as the elbow's on the sides in `elbows`
    (elbow_sides), as the knee's elsewhere."""
    out = []
    for side, name in _readings(label):
        if side is not None and side in elbows and name in EPICONDYLE:
            out.append((side + "ELB", len(SIDE_ALIASES["ELB"]) + EPICONDYLE.index(name)))
        elif side is not None and name in _SIDE_LOOKUP:
            code, rank = _SIDE_LOOKUP[name]
            out.append((side + code, rank))
        if side is None and name in _MIDLINE_LOOKUP:
            out.append(_MIDLINE_LOOKUP[name])
    return out


def plug_in_gait_name(label: str) -> str | None:
    """The Plug-in Gait label a trial label is a common spelling of, by the alias table alone (LTHI for L_Thigh,
    SACR for V.Sacral, LPSI for L.PSIS), whatever the model calls it; None for no known spelling."""
    codes = _codes(label)
    return codes[0][0] if codes else None


def _and_unprefixed(label: str) -> list[str]:
    """`label`, and its name after a subject prefix where it has one (``BodyL:HandL`` -> ``HandL``)."""
    return [label] + ([split[1]] if (split := _split_prefix(label)) else [])


def _bare_epicondyle(label: str) -> bool:
    """Whether `label` (or its name after a prefix) reads as a lateral epicondyle that names no bone (EPICONDYLE)."""
    return any(side is not None and name in EPICONDYLE for n in _and_unprefixed(label) for side, name in _readings(n))


def elbow_sides(labels: Iterable[str]) -> frozenset[str]:
    """The sides ('R', 'L') on which a trial's bare lateral epicondyle (EPICONDYLE) is the elbow's: that side's other
    labels (read by the alias table, whole or after a subject prefix) show none of the leg's markers below the hip
    (LEG_CODES) and some of the arm's (ARM_CODES, the acromion's among them), on that side or, where the trial shows
    no leg marker at all, on either; or they show that side's knee marker and its arm's but not its elbow's.  The
    knee's elsewhere, as the table reads it alone (a leg's set with a knee marker beside: no arm, no elbow)."""
    shown: set[str] = set()
    for label in labels:
        if _bare_epicondyle(label):
            continue
        code = next((c[0][0] for n in _and_unprefixed(label) if (c := _codes(n))), None)
        if code is not None:
            shown.add(code)
    legs = {side: {c for c in LEG_CODES if side + c in shown} for side in "RL"}
    arms = {side: {c for c in ARM_CODES if side + c in shown} for side in "RL"}
    armed = any(arms.values()) and not any(legs.values())  # an upper body's trial (a wheelchair's, a shoulder's)
    return frozenset(side for side in "RL" if (not legs[side] and (arms[side] or armed))
                     or ("KNE" in legs[side] and arms[side] and "ELB" not in arms[side]))


OSIM_INVALID_CHARS = "\\*+ \t\n/"  # OpenSim's ComponentPath.getInvalidChars()


def osim_name(label: str) -> str:
    """`label` as an OpenSim marker may be named: each character OpenSim does not allow in names (OSIM_INVALID_CHARS)
    as '_' (BTS's Davis labels: 'r bar 1' -> 'r_bar_1').  A calibrated subject's .osim names a new marker so; its
    trials' label is read as that marker (map_labels)."""
    return "".join("_" if c in OSIM_INVALID_CHARS else c for c in label)


def alias_for(label: str, model_labels: Iterable[str],
              elbows: frozenset[str] = frozenset()) -> tuple[str, int] | None:
    """The model label a trial label is a common spelling of, and its rank in the alias table (0 best).

    The model's own Plug-in Gait label where it has one; else the model label that spells the same landmark
    (Rajagopal2016's ``L.Knee`` for a trial's ``L_Knee_Lat``, both the lateral knee), the most specific spelling
    where several do (``L.Ankle`` before ``LLMAL``).  None when the label is no known spelling of any of
    ``model_labels``.  `elbows`: the sides on which a bare lateral epicondyle is the elbow's (elbow_sides).
    """
    labels = list(model_labels)
    model = set(labels)
    codes = _codes(label, elbows)
    for code, rank in codes:
        if code in model:
            return code, rank
    if not codes:
        return None
    spelled: dict[str, tuple[int, int, str]] = {}  # Plug-in Gait label -> (its alias rank, model order, model label)
    for k, m in enumerate(labels):
        mine = _codes(m)
        if mine and mine[0][0] not in spelled:
            spelled[mine[0][0]] = (mine[0][1], k, m)
        elif mine and (mine[0][1], k) < spelled[mine[0][0]][:2]:
            spelled[mine[0][0]] = (mine[0][1], k, m)
    for code, rank in codes:
        if code in spelled:
            return spelled[code][2], rank
    return None


# ---------------------------------------------------------------------------
# The marker map file
# ---------------------------------------------------------------------------


def _map_error(source: str | None, what: str, todo: str) -> CalibrateError:
    return CalibrateError(" ".join(f"{source or 'marker map'}: {what}; {todo}".split()))


def load_marker_map(path: str | os.PathLike[str]) -> MarkerMap:
    """Read a marker map TOML file: ``MODEL_LABEL = ["trial label", ...]`` (a single string also works).

    Raises CalibrateError (one line naming the file, the key and what to do) when the file is
    missing or not TOML, an entry is not a list of non-empty labels, or one trial label is listed
    under two model labels.  Model labels are checked against the model by :func:`map_labels`.
    """
    path = Path(path)
    where = str(path)
    if not path.exists():
        raise _map_error(where, "no such file", "check the path of the marker map")
    if path.is_dir():
        raise _map_error(where, "is a directory, not a marker map", "give the path of a .toml file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise _map_error(where, "is not UTF-8 text", "save the marker map as UTF-8 TOML") from None
    except OSError as exc:
        raise _map_error(where, f"cannot be read ({exc.strerror or exc})", "check the file permissions") from None
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise _map_error(
            where, f"not valid TOML ({exc})", 'write one line per model label, e.g. RASI = ["R.ASIS", "RASIS"]'
        ) from None

    marker_map = MarkerMap()
    marker_map.source = where
    owner: dict[str, str] = {}
    segments = table.pop(SEGMENTS, None)
    if segments is not None and not isinstance(segments, dict):
        raise _map_error(where, f"{SEGMENTS} = {segments!r} is not a table",
                         'write it as a table: [segments] then femur_l = ["LTH1", "LTH2"], after the model labels')
    for key, value in table.items():
        example = f'write it as {key} = ["R.ASIS", "RASIS"] (model label = list of trial labels)'
        if isinstance(value, str):
            value = [value]
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            shown = "a table" if isinstance(value, dict) else repr(value)
            raise _map_error(where, f"{key} = {shown} is not a list of trial labels", example)
        labels = [v.strip() for v in value]
        if not labels:
            raise _map_error(where, f"{key} lists no trial labels", "add its trial labels or remove the line")
        if not all(labels):
            raise _map_error(where, f"{key} lists an empty trial label", "remove the empty string")
        if not key.strip() or key != key.strip():
            raise _map_error(where, f"model label {key!r} is blank or has surrounding spaces", "fix the name")
        unique: list[str] = []
        for label in labels:
            if label in owner and owner[label] != key:
                raise _map_error(
                    where,
                    f"trial label {label!r} is listed under both {owner[label]} and {key}",
                    "list it under one model label only",
                )
            if label not in unique:
                unique.append(label)
            owner[label] = key
        marker_map[key] = unique
    declared = _segment_table(segments or {}, where)
    for label, segment in declared.items():
        if label in owner:
            raise _map_error(where, f"trial label {label!r} is listed under model label {owner[label]} and under "
                                    f"[segments] {segment}", "a label is either the model's marker or a new one: list "
                                                             "it once")
        marker_map.segments.setdefault(segment, []).append(label)
    return marker_map


def _check_marker_map(marker_map: Mapping[str, Sequence[str]], model: Sequence[str]) -> dict[str, tuple[str, int]]:
    """Trial label -> (model label, position in its list), after checking the map against the model."""
    source = getattr(marker_map, "source", None)
    model_set = set(model)
    lookup: dict[str, tuple[str, int]] = {}
    for key, labels in marker_map.items():
        if key == SEGMENTS and isinstance(labels, Mapping) and key not in model_set:
            continue  # the new labels' segments (declared_segments)
        if key not in model_set:
            shown = ", ".join(model[:12]) + (f" and {len(model) - 12} more" if len(model) > 12 else "")
            raise _map_error(
                source,
                f"model label {key!r} is not in the model (its markers: {shown or 'none'})",
                "correct the name or remove the line",
            )
        if isinstance(labels, str):
            labels = [labels]
        for position, label in enumerate(labels):
            if not isinstance(label, str) or not label.strip():
                raise _map_error(source, f"{key} lists {label!r}, not a trial label", "give labels as text")
            label = label.strip()
            if label in lookup and lookup[label][0] != key:
                raise _map_error(
                    source,
                    f"trial label {label!r} is listed under both {lookup[label][0]} and {key}",
                    "list it under one model label only",
                )
            lookup.setdefault(label, (key, position))
    return lookup


# ---------------------------------------------------------------------------
# Mapping
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class LabelMatch:
    """What one trial label became: ``label`` (the label in the relabelled trial), ``how`` (one of
    :data:`HOWS`) and a ``note`` (a conflict, a prefix that was passed over) or ''."""

    trial_label: str
    label: str
    how: str
    note: str = ""


@dataclass(frozen=True)
class LabelMapping:
    """Every trial label and what it became, in trial order; model labels no trial label gave; warnings."""

    matches: tuple[LabelMatch, ...]
    missing: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()

    def __iter__(self) -> Iterator[LabelMatch]:
        return iter(self.matches)

    def __len__(self) -> int:
        return len(self.matches)

    @property
    def renamed(self) -> dict[str, str]:
        """Trial label -> label in the relabelled trial, for every trial label."""
        return {m.trial_label: m.label for m in self.matches}

    @property
    def unknown(self) -> tuple[str, ...]:
        """Trial labels that did not become a model label."""
        return tuple(m.trial_label for m in self.matches if m.how == "unknown")

    def to_json(self) -> list[dict[str, str]]:
        """One dict per trial label: ``trial_label``, ``label``, ``how``, ``note``."""
        return [{"trial_label": m.trial_label, "label": m.label, "how": m.how, "note": m.note} for m in self.matches]

    def text(self) -> str:
        """A short table: trial label, what it became (``=`` unchanged), how, note; counts; model labels not found."""
        rows = [("trial label", "label", "how", "note")]
        rows += [(m.trial_label, m.label if m.label != m.trial_label else "=", m.how, m.note) for m in self.matches]
        widths = [max(len(row[i]) for row in rows) for i in range(3)]
        lines = [
            "  ".join(cell.ljust(width) for cell, width in zip(row[:3], widths, strict=True)) + "  " + row[3]
            for row in rows
        ]
        lines = [line.rstrip() for line in lines]
        counts = {how: sum(m.how == how for m in self.matches) for how in HOWS}
        lines.append(", ".join(f"{counts[how]} {how}" for how in HOWS if how != "description" or counts[how]))
        if self.missing:
            lines.append(f"model labels not in the trial ({len(self.missing)}): {', '.join(self.missing)}")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.text()


def _split_prefix(label: str) -> tuple[str, str] | None:
    """(prefix, name) of a label ``prefix:name``, or None."""
    if ":" not in label:
        return None
    prefix, name = label.split(":", 1)
    prefix, name = prefix.strip(), name.strip()
    return (prefix, name) if prefix and name else None


def _with_mapped_outputs(trial: Trial, lookup: Mapping[str, tuple[str, int]],
                         model_set: set[str], aliases: bool = True) -> tuple[Trial, dict[str, str]]:
    """The trial with the model outputs (points a modelling program wrote, io.c3d) that the marker map names or that
    are the model's own marker by their name read as markers, and why each was: Plug-in Gait's knee centre ``LFEO``
    mapped to a lab's ``LKJC``, or pyCGM2's computed ``LKJC`` where the lab's marker set has a marker ``LKJC`` at the
    knee centre.  The file's parameters or the label's name alone keep such points apart; the user's map or model
    naming one is the word that it is a marker.  So is a point named exactly as Plug-in Gait names a marker of the
    model's that the aliases read under another spelling, where no marker of the trial is read as it (`aliases`):
    Plug-in Gait's knee marker ``LKNE`` that a knee alignment device's static carries as an output, gait2392's
    ``L.Knee.Lat``, as it is models/human.urdf's ``LKNE``."""
    why = {label: "the marker map names it" if label in lookup else "the model has a marker of its name"
           for label in trial.model_outputs
           if (label in lookup or label in model_set) and trial.output_kinds.get(label) == "point"
           and label not in trial.labels}
    if aliases:
        shown = {found[0] for label in trial.labels if (found := alias_for(label, model_set)) is not None}
        for label in trial.model_outputs:
            found = alias_for(label, model_set) if label not in why and label not in trial.labels else None
            if (found is not None and trial.output_kinds.get(label) == "point" and found[0] not in shown
                    and found[0] not in trial.labels and plug_in_gait_name(found[0]) == label):
                why[label] = f"Plug-in Gait's name of the model's {found[0]}"
    if not why:
        return trial, why
    named = list(why)
    extra = np.stack([np.asarray(trial.model_outputs[label], dtype=float) for label in named], axis=1)
    markers = np.concatenate([np.asarray(trial.markers), extra], axis=1)
    markers.flags.writeable = False
    keep = {k: v for k, v in trial.model_outputs.items() if k not in why}
    return replace(trial, labels=(*trial.labels, *named), markers=markers, model_outputs=keep,
                   output_kinds={k: v for k, v in trial.output_kinds.items() if k in keep},
                   output_units={k: v for k, v in trial.output_units.items() if k in keep}), why


def map_labels(
    trial: Trial,
    model_labels: Sequence[str],
    marker_map: Mapping[str, Sequence[str]] | None = None,
    aliases: bool = True,
) -> tuple[Trial, LabelMapping]:
    """Rename a trial's markers to model labels; return the relabelled trial and what each label became.

    ``marker_map``: model label -> trial labels (as :func:`load_marker_map` reads it).  The user's word, it
    takes precedence over everything: over a trial label that is the model's own name (that label is then
    renamed with the first free suffix, ``RKNE_2``, and placed like any unknown label) and over the built-in
    aliases (``aliases=False`` turns those off).  A label that matches nothing by its own name is read by the
    file's description of it (``Trial.descriptions``: ``RK``, "Right knee"), after every name.  Labels that
    match nothing are kept as they are.  A model output of the file (``Trial.model_outputs``, a point) that the map
    names, or that the model has a marker of its name, joins the markers (:func:`_with_mapped_outputs`; the label's
    note says which).  Rate, first frame and source are unchanged.
    Raises CalibrateError when the map names a model label the model does not have, or when the
    trial holds the markers of several subjects (prefixes ``Derrick:``, ``Viktor:``, each matching
    SUBJECT_MARKERS of the model's or more): ``trial.of_subject(name)`` picks one.
    """
    if not isinstance(trial, Trial):
        raise TypeError(f"expected a Trial, got {type(trial).__name__}")
    if isinstance(model_labels, str):
        raise TypeError("model_labels must be a sequence of labels, not one string")
    model = [str(label) for label in model_labels]
    model_set = set(model)
    lookup = _check_marker_map(marker_map, model) if marker_map else {}
    trial, outputs = _with_mapped_outputs(trial, lookup, model_set, aliases)
    # New labels by the user's word, kept as they are; one the model has (a subject calibrated with this map, which
    # carries them) is its own marker (calibrate() refuses a base model's: pipeline.calibrate).
    declared = {lab: seg for lab, seg in declared_segments(marker_map).items() if lab not in model_set}
    elbows = elbow_sides(trial.labels) if aliases else frozenset()

    def best(label: str) -> tuple[str, str, float] | None:
        """(model label, how, priority) of a whole label."""
        if label in lookup:  # the user's word first, over a label that happens to be the model's (a BTS file's RKNE
            return lookup[label][0], "map", lookup[label][1]  # is its computed knee centre; RKNE1 the epicondyle)
        if label in model_set:
            return label, "exact", 0
        if (named := osim_name(label)) != label and named in model_set:  # its marker in a subject's .osim
            return named, "exact", 0
        if aliases:
            found = alias_for(label, model_set, elbows)
            if found is not None:
                # OpenCap's augmented marker (r_knee_study: the lateral epicondyle, where RKNE sits) before a video
                # keypoint of the same name (RKnee: the knee's centre as a pose estimator puts it), in one file.
                return found[0], "alias", found[1] - (0.5 if _augmented(label) else 0.0)
        return None

    # Each trial label's best candidate: (model label, how, rank key, note)
    candidates: dict[int, tuple[str, str, tuple[int, int, float], str]] = {}
    subjects: dict[str, int] = {}  # prefix -> model markers its labels match
    for index, label in enumerate(trial.labels):
        if label in declared:  # a new label on the segment the map's [segments] names: not read as another
            continue
        found = best(label)
        prefixed = 0
        note = ""
        if found is None and (split := _split_prefix(label)) is not None:
            found = best(split[1])
            prefixed, note = 1, f"matched after the prefix {split[0]}:"
            if found is not None:
                subjects[split[0]] = subjects.get(split[0], 0) + 1
        if found is None and aliases and (said := trial.descriptions.get(label)):
            # a code the file describes (c3d.org's sample10: RK, "Right knee"), read as its description's alias
            if (by := alias_for(said, model_set, elbows)) is not None:  # after any name, a subject's prefixed ones too
                found, prefixed, note = (by[0], "description", by[1]), 2, f"by its description '{said}'"
        if found is not None:
            target, how, priority = found
            if how == "alias" and _bare_epicondyle(label):  # the trial's other labels chose the bone: say so
                elbow = (plug_in_gait_name(target) or "").endswith("ELB")
                note = "; ".join(filter(None, [note, "a lateral epicondyle of no named bone: the " + (
                    "elbow's, as the trial's other labels show that arm and not its leg, no leg, or its knee "
                    "otherwise" if elbow else "knee's, as the trial's other labels do not show that arm alone")]))
            candidates[index] = (target, how, (prefixed, _RANK[how], priority), note)
    several = {k: n for k, n in subjects.items() if n >= SUBJECT_MARKERS}
    if len(several) > 1:  # a session's file with each subject's markers (Vicon's Derrick:RASI, Viktor:RASI)
        raise CalibrateError(
            f"{trial.source or 'trial'}: holds the markers of {len(several)} subjects ("
            + ", ".join(f"{k}: {n} of the model's" for k, n in several.items())
            + f"); calibrate one at a time: --subject {next(iter(several))} on the command line, "
            "trial.of_subject(NAME) in Python")

    by_target: dict[str, list[int]] = {}
    for index, (target, *_rest) in candidates.items():
        by_target.setdefault(target, []).append(index)

    labels = list(trial.labels)
    hows = ["unknown"] * len(labels)
    notes = [f"on {declared[lab]} ([segments])" if lab in declared else "" for lab in labels]
    messages: list[str] = []
    for target, indices in by_target.items():
        indices.sort(key=lambda i: (candidates[i][2], i))
        winner, losers = indices[0], indices[1:]
        labels[winner] = target
        hows[winner] = candidates[winner][1]
        notes[winner] = candidates[winner][3]
        if not losers:
            continue
        loser_names = ", ".join(trial.labels[i] for i in losers)
        notes[winner] = "; ".join(filter(None, [notes[winner], f"conflict: kept over {loser_names}"]))
        for i in losers:
            notes[i] = f"conflict: {target} kept {trial.labels[winner]}"
        tied = [i for i in losers if candidates[i][2] == candidates[winner][2]]
        if tied:
            names = ", ".join(trial.labels[i] for i in [winner, *tied])
            message = (
                f"trial labels {names} all match {target} equally well; kept {trial.labels[winner]}, "
                "the first in the trial (a marker map can choose)"
            )
            messages.append(message)
            warnings.warn(message, LabelConflictWarning, stacklevel=2)

    for i, label in enumerate(trial.labels):
        if label in outputs:
            read = f"a model output of the file, read as a marker: {outputs[label]}"
            notes[i] = "; ".join(filter(None, [notes[i], read]))
    # A label the map displaced from the model's name it carries (the map gave RKNE to RKNE1) takes the first free
    # suffix, as a file's repeated label does (RKNE_2), and is placed like any unknown label.
    taken = set(labels)
    for i, label in enumerate(labels):
        if hows[i] == "unknown" and label in model_set:
            n = 2
            while f"{label}_{n}" in taken:
                n += 1
            labels[i] = f"{label}_{n}"
            taken.add(labels[i])
            notes[i] = f"{notes[i]}; renamed {labels[i]}"
    if len(set(labels)) != len(labels):  # cannot happen: unknown labels are never model labels
        raise CalibrateError(f"{trial.source or 'trial'}: relabelling made two markers the same; check the marker map")
    relabelled = replace(trial, labels=tuple(labels))
    matches = tuple(
        LabelMatch(trial_label=old, label=new, how=how, note=note)
        for old, new, how, note in zip(trial.labels, labels, hows, notes, strict=True)
    )
    found_targets = set(by_target)
    missing = tuple(label for label in model if label not in found_targets)
    return relabelled, LabelMapping(matches=matches, missing=missing, warnings=tuple(messages))
