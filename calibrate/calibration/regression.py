"""Hip joint centres by regression from the pelvis markers (Settings.hip_regression, ``--hip-regression``).

A walk does not place the hips: thigh skin artefact that follows hip flexion is, for the thigh's markers, the
same signal as a displaced hip centre, and on the three real recordings the walk-fitted hips end 28–65 mm from
the labs' centres and from Harrington's regression (docs/benchmarks.md, "Hip centres from a walk").  Gait labs
place them by regression from the pelvis landmarks; this does the same: Harrington et al. (2007, J Biomech
40:595), the regression a CT study found nearest (12 ± 6 mm), is computed in every frame from the trials' ASIS
and PSIS markers (or the sacral marker as the PSIS midpoint) and added as a virtual marker at each hip centre,
which calibrate keeps there as a joint-centre marker (calibrate.problem.priors.joint_centre_markers).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import CalibrateError
from ..io.labels import alias_for
from ..io.trial import Trial
from ..model.model import Joint, Model, add_markers

#: A hip centre is placed by motion only through enough range in two of its three angles (a star arc: flexion
#: and abduction, 30 deg each in the functional-calibration protocols); real walks turn the hips through 10-15 deg
#: in their second (gait2392, rajagopal_walk, pig_walk), the simulator's squats through 19-40 deg.
FUNCTIONAL_RANGE = math.radians(20.0)
LANDMARKS = ("RASI", "LASI", "RPSI", "LPSI", "SACR")  # Plug-in Gait's names; other spellings by alias
#: The virtual markers' labels (model and trials), right and left.
VIRTUAL = ("RHJC_harrington", "LHJC_harrington")


def harrington(rasi: np.ndarray, lasi: np.ndarray, psis_mid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Right and left hip centres (n, 3) from the ASIS markers and the PSIS midpoint (n, 3), metres, by
    Harrington et al. (2007): in the pelvis frame at mid-ASIS (z to the right ASIS, x anterior towards it
    from the PSIS midpoint, y up), x = −0.24 PD − 9.9 mm, y = −0.30 PW − 10.9 mm, z = ±(0.33 PW + 7.3 mm),
    PW the ASIS distance and PD the mid-ASIS to mid-PSIS distance."""
    o, x, y, z, pw, pd = _pelvis_frame(rasi, lasi, psis_mid)
    mid = o + x * (-0.24 * pd - 0.0099) + y * (-0.30 * pw - 0.0109)
    side = z * (0.5 * harrington_width(pw))
    return mid + side, mid - side


def _pelvis_frame(rasi: np.ndarray, lasi: np.ndarray, psis_mid: np.ndarray) -> tuple[np.ndarray, ...]:
    """Harrington's pelvis frame: origin mid-ASIS, unit axes x (anterior), y (up), z (to the right ASIS), each (n, 3),
    and PW, PD (n, 1): the ASIS distance and the mid-ASIS to mid-PSIS distance."""
    o = 0.5 * (rasi + lasi)
    z = rasi - lasi
    pw = np.linalg.norm(z, axis=-1, keepdims=True)
    z = z / pw
    x = o - psis_mid
    pd = np.linalg.norm(x, axis=-1, keepdims=True)
    x = x - z * np.sum(x * z, axis=-1, keepdims=True)
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    y = np.cross(z, x)
    return o, x, y, z, pw, pd


def model_offsets(model: Model) -> dict[str, tuple[np.ndarray, float]]:
    """Where the base model itself puts each hip from Harrington's regression on its own pelvis markers, in its
    default pose: side -> ((dx / PD, dy / PW, dz / PW) in Harrington's pelvis frame (_pelvis_frame), so that on a
    subject's pelvis Harrington's point plus that offset, at the subject's PW and PD, is where the base model's
    convention puts the hip; the offset's length on the base model, m).  {} where the model lacks a hip or a
    landmark.  gait2392's hips lie 36 mm from Harrington's on its own markers (with its scale marker set; its
    V.Sacral read as the PSIS midpoint), Rajagopal2016's 22 mm, models/human.urdf's 7.5 mm."""
    import pinocchio as pin

    hips = hip_joints(model)
    found = _landmarks(model)
    back = ("RPSI", "LPSI") if {"RPSI", "LPSI"} <= set(found) else ("SACR",) if "SACR" in found else None
    if set(hips) != {"r", "l"} or not {"RASI", "LASI"} <= set(found) or back is None:
        return {}
    pm = model.pin
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, pin.neutral(pm))

    def at(label: str) -> np.ndarray:
        return data.oMf[pm.getFrameId(label, pin.FrameType.BODY)].translation.copy()

    mid = 0.5 * (at(found["RPSI"]) + at(found["LPSI"])) if back != ("SACR",) else at(found["SACR"])
    o, x, y, z, pw, pd = (v[0] for v in _pelvis_frame(at(found["RASI"])[None], at(found["LASI"])[None], mid[None]))
    right, left = (v[0] for v in harrington(at(found["RASI"])[None], at(found["LASI"])[None], mid[None]))
    out = {}
    for side, h in (("r", right), ("l", left)):
        joint = model.joints[model.joint_index(hips[side].name)]
        first = next(u for u in model.urdf_joints if u.name in joint.urdf_joints)
        hip = data.oMi[pm.getJointId(first.name)].translation if pm.existJointName(first.name) else None
        if hip is None:
            return {}
        d = hip - h
        out[side] = (np.array([d @ x / pd[0], d @ y / pw[0], d @ z / pw[0]]), float(np.linalg.norm(d)))
    return out


def harrington_width(asis_width: np.ndarray | float) -> np.ndarray | float:
    """The distance between Harrington's two hip centres (m) for an ASIS distance PW (m): 2 (0.33 PW + 7.3 mm)."""
    return 0.66 * asis_width + 0.0146


def hip_joints(model: Model, pelvis: str | None = None) -> dict[str, Joint]:
    """The model's hips: 'r' and 'l' -> its ball joint named hip_r / hip_l (any spelling starting with 'hip' and
    ending in _r / _l), below `pelvis` if given."""
    hips = {}
    for j in model.joints:
        if j.kind == "ball" and j.name.lower().startswith("hip") and (pelvis is None or j.parent == pelvis):
            side = j.name.lower()[-2:]
            if side in ("_r", "_l"):
                hips[side[1]] = j
    return hips


#: Where the trials' motion does not place a hip, its centre further than REGRESSION_FAR from Harrington's regression
#: (its error on CT 12 +- 6 mm; the simulator's subjects, their centres and markers drawn apart by up to 15 mm per
#: coordinate, 9-29 mm), or the two hips further apart than HIP_WIDTH_FAR times the ASIS markers (Harrington's
#: 0.66 times plus 15 mm; the simulator's 0.64-0.74) is implausible: BTKData's PiG walks ended their hips 46-93 mm
#: from Harrington's and up to 1.25 times the ASIS width apart, outside the pelvis (docs/benchmarks.md).
REGRESSION_FAR = 0.040
HIP_WIDTH_FAR = 0.9
#: A base model whose own hips lie further than MODEL_OFFSET from Harrington's regression on its own pelvis markers
#: (beyond the regression's error on CT, 12 +- 6 mm) has a convention of its own: a hip within REGRESSION_FAR of
#: where that convention puts it on the trials' markers is where the lab's model puts hips, not implausible
#: (HipMotion.as_model)
MODEL_OFFSET = 0.015
#: ... and wherever the motion places them, two hips further apart than the ASIS markers themselves lie outside the
#: pelvis, where no hip is (Harrington's width is 0.66 times the ASIS markers' plus 15 mm, 0.73 at 220 mm; the real
#: walks whose motion placed the hips 0.79-0.95): c3d.org's sample04, a thigh whose markers do not fix its turn about
#: its length (hip_r rotation over 122 deg), ended them 1.35 times the ASIS width apart, 75 mm from Harrington's.
HIP_OUTSIDE = 1.0
#: ... nor two hips closer together than HIP_NARROW times the ASIS markers: drawn onto the pelvis's midline, where no
#: hip is either (Harrington's 0.73 at 220 mm; a lab's functional centres, OpenCap's, 0.81; the narrowest real run
#: otherwise, BTKData's ADemo1, 0.57): BTKData's 561xxa01 on Rajagopal2016.osim, its thighs' own markers not in the
#: model's set, ended them 29 mm apart where the ASIS markers are 214.
HIP_NARROW = 0.5
#: hip_regression "auto" keeps the calibration with the regression only where its marker RMS is within HIP_AUTO_COST
#: times the one without, unless the hips without it lie outside the pelvis (HIP_OUTSIDE: no hip is there, whatever
#: the fit).  Imposed where the markers place the hips against it, the regression costs the fit: on the eleven real
#: runs where it fired the RMS rose by at most 1.17 times where it did no harm (Expert1's walk, its hips then 11-15 mm
#: from the lab's own hip centres instead of 26-27), and by 1.35 and 2.03 times where it did (AddBiomechanics'
#: treadmill walk, its knee and ankle axes then turned 43-58 deg; OpenCap's squats), docs/benchmarks.md.
HIP_AUTO_COST = 1.25


@dataclass(frozen=True)
class HipMotion:
    """How far the trials turn a hip: each of its three angles' range (5th to 95th percentile of its frames, the
    largest over the trials, rad).  Through less than FUNCTIONAL_RANGE in two of them the motion does not place the
    centre (on real walks it ends 28-65 mm from the labs' and Harrington's: docs/benchmarks.md).
    `from_regression`: the calibrated centre's distance (m, median over the trials' frames) from Harrington's
    regression on the trials' pelvis markers (NaN without them); `width`: the two hip centres' distance and the
    ASIS markers' (m, medians), the same for both hips."""

    joint: str
    ranges: dict[str, float]
    from_regression: float = math.nan
    width: tuple[float, float] = (math.nan, math.nan)
    # the calibrated centre's distance (m, median) from where the base model's own convention puts the hip on the
    # trials' pelvis markers (Harrington's point plus the base model's offset from it, model_offsets), and that
    # offset's length on the base model (m): gait2392 places its hips 36 mm from Harrington's on its own markers
    from_model: float = math.nan
    model_offset: float = math.nan

    @property
    def as_model(self) -> bool:
        """Far from Harrington's only as far as the base model's own hips are (its offset more than MODEL_OFFSET, the
        centre within REGRESSION_FAR of the base model's convention): the lab's model, not the calibration, puts it
        there (a simulated gait2392 walk's hips 44-47 mm from Harrington's, 18-21 mm from the base model's convention,
        7-9 mm from the truth)."""
        return bool(self.model_offset > MODEL_OFFSET and self.from_model <= REGRESSION_FAR)

    @property
    def places_centre(self) -> bool:
        return sorted(self.ranges.values())[-2] >= FUNCTIONAL_RANGE

    @property
    def implausible(self) -> bool:
        """A centre the motion does not place, ended further than REGRESSION_FAR from Harrington's or the hips
        further apart than HIP_WIDTH_FAR times the ASIS markers; or, placed by the motion or not, the hips where no
        hip is (nowhere: further apart than HIP_OUTSIDE times the ASIS markers, or closer together than HIP_NARROW)."""
        return self.nowhere or not self.places_centre and not self.as_model and (
            self.from_regression > REGRESSION_FAR or self.width[0] > HIP_WIDTH_FAR * self.width[1])

    @property
    def outside(self) -> bool:
        """The two hips further apart than HIP_OUTSIDE times the ASIS markers: outside the pelvis."""
        return bool(self.width[0] > HIP_OUTSIDE * self.width[1])

    @property
    def narrow(self) -> bool:
        """The two hips closer together than HIP_NARROW times the ASIS markers: on the pelvis's midline."""
        return bool(self.width[0] < HIP_NARROW * self.width[1])

    @property
    def nowhere(self) -> bool:
        """The hips where no hip is, whatever the markers say: outside the pelvis or on its midline."""
        return self.outside or self.narrow

    def text(self) -> str:
        """e.g. 'hip_l through flexion 31, adduction 8, rotation 13 deg' (the DoF names without the joint's)."""
        own = set(self.joint.split("_"))
        return f"{self.joint} through " + ", ".join(
            f"{'_'.join(w for w in d.split('_') if w not in own) or d} {math.degrees(v):.0f}"
            for d, v in self.ranges.items()) + " deg"

    def to_json(self) -> dict:
        out = {"joint": self.joint, "range_deg": {k: math.degrees(v) for k, v in self.ranges.items()},
               "places_centre": self.places_centre}
        if math.isfinite(self.from_regression):
            out.update(from_regression_mm=1e3 * self.from_regression, implausible=self.implausible,
                       hip_width_mm=1e3 * self.width[0], asis_width_mm=1e3 * self.width[1])
        if math.isfinite(self.from_model):
            out.update(from_model_mm=1e3 * self.from_model, model_offset_mm=1e3 * self.model_offset,
                       as_model=self.as_model)
        return out


def hip_motion(model: Model, motions: Sequence, centres: Sequence[tuple[np.ndarray, np.ndarray]] = (),
               trials: Sequence[Trial] = (), base: Model | None = None) -> tuple[HipMotion, ...]:
    """HipMotion of each hip (hip_joints) over `motions` (calibrate.io.motion.Motion per trial, the model's DoFs);
    with `centres` (per trial: its frames' indices and the calibrated joint centres in the lab there, (n, n_joints,
    3)) and `trials` (the model's labels), each hip centre's distance from Harrington's regression on those frames,
    where the trials carry the pelvis landmarks; with `base` (the base model) also its distance from where the base
    model's own convention puts it there (model_offsets)."""
    out = []
    hips = hip_joints(model)
    offsets = model_offsets(base) if base is not None else {}
    ref = _regression_reference(model, hips, centres, trials, offsets)
    for side in ("l", "r"):
        joint = hips.get(side)
        if joint is None:
            continue
        ranges = {}
        for d in joint.dofs:
            spans = [float(np.diff(np.percentile(m.angles[:, m.dof_names.index(d)], [5, 95]))[0])
                     for m in motions if m.n_frames and d in m.dof_names]
            if spans:
                ranges[d] = max(spans)
        if len(ranges) == 3:
            out.append(HipMotion(joint.name, ranges, *ref.get(side, (math.nan, (math.nan, math.nan), math.nan,
                                                                     math.nan))))
    return tuple(out)


def _landmarks(model: Model) -> dict[str, str]:
    """The model's pelvis landmarks Harrington's regression reads: Plug-in Gait name -> the model's label."""
    found: dict[str, str] = {}
    for mk in model.markers:
        hit = mk.name if mk.name in LANDMARKS else (alias_for(mk.name, LANDMARKS) or (None,))[0]
        if hit is not None and hit not in found:
            found[hit] = mk.name
    return found


def _pelvis_landmarks(model: Model, trials: Sequence[Trial]) -> dict[str, str]:
    """The pelvis landmarks Harrington's regression reads in `trials`: the model's (_landmarks), and the trials' own
    where the model lacks them."""
    found = _landmarks(model)
    if "SACR" not in found and (sacrum := _trials_label(trials, "SACR")):
        # A sacral marker every trial carries and the model does not (a lab's SACR beside a model with PSIS markers:
        # c3d.org's sample04 has no PSIS) stands in for the PSIS midpoint, as a model's own would.
        found["SACR"] = sacrum
    if not _carried(trials, found) and (psis := _trials_psis(trials)):
        # The trials' own PSIS markers where they carry none of the model's back landmarks (Plug-in Gait's LPSI and
        # RPSI on gait2392, whose pelvis has a V.Sacral): their midpoint is the sacrum the regression reads.
        found.update(psis)
        found.pop("SACR", None)
    return found


def _trials_label(trials: Sequence[Trial], code: str) -> str | None:
    """The label of Plug-in Gait's landmark `code` (its name or an alias of it) that every one of `trials` carries, or
    None."""
    common = set.intersection(*(set(t.labels) for t in trials)) if trials else set()
    hits = sorted(lab for lab in common if lab == code or (alias_for(lab, (code,)) or (None,))[0] == code)
    return hits[0] if hits else None


def _carried(trials: Sequence[Trial], found: dict[str, str]) -> bool:
    """Whether every one of `trials` carries the back landmarks of `found` the regression reads (both PSIS, or the
    sacrum)."""
    return all({found.get("RPSI"), found.get("LPSI")} <= set(t.labels) or found.get("SACR") in t.labels
               for t in trials)


def _trials_psis(trials: Sequence[Trial]) -> dict[str, str]:
    """{'RPSI': label, 'LPSI': label}: the PSIS markers (Plug-in Gait's names or an alias of them) every one of
    `trials` carries, or {}."""
    out = {code: lab for code in ("RPSI", "LPSI") if (lab := _trials_label(trials, code)) is not None}
    return out if len(out) == 2 else {}


def _harrington_of(trial: Trial, found: dict[str, str], frames: np.ndarray | slice = slice(None)
                   ) -> tuple[np.ndarray, np.ndarray, dict[str, str]] | None:
    """Harrington's right and left hip centres in each of `frames` of `trial` (NaN where a landmark is not seen) and
    the landmarks read, or None when the trial lacks an ASIS or both PSIS and the sacral marker."""
    have = {c: label for c, label in found.items() if label in trial.labels}
    back = ("RPSI", "LPSI") if "RPSI" in have and "LPSI" in have else ("SACR",) if "SACR" in have else None
    if "RASI" not in have or "LASI" not in have or back is None:
        return None
    at = {c: trial.markers[frames, trial.labels.index(have[c])] for c in ("RASI", "LASI", *back)}
    mid = 0.5 * (at["RPSI"] + at["LPSI"]) if back != ("SACR",) else at["SACR"]
    with np.errstate(invalid="ignore"):
        right, left = harrington(at["RASI"], at["LASI"], mid)
    return right, left, {c: have[c] for c in at}


def _regression_reference(model: Model, hips: dict[str, Joint], centres: Sequence[tuple[np.ndarray, np.ndarray]],
                          trials: Sequence[Trial], offsets: dict[str, tuple[np.ndarray, float]] | None = None
                          ) -> dict[str, tuple[float, tuple[float, float], float, float]]:
    """Per side: the calibrated hip centre's median distance from Harrington's over every frame given, the hip
    centres' and ASIS markers' median widths there, and with `offsets` (model_offsets) its median distance from the
    base model's convention and that offset's length on the base model (NaN without)."""
    if set(hips) != {"r", "l"} or not centres:
        return {}
    found = _pelvis_landmarks(model, trials)
    k = {side: model.joint_index(hips[side].name) for side in "rl"}
    gaps: dict[str, list[np.ndarray]] = {"r": [], "l": []}
    conv: dict[str, list[np.ndarray]] = {"r": [], "l": []}
    widths, asis = [], []
    for (frames, C), t in zip(centres, trials, strict=True):
        h = _harrington_of(t, found, frames)
        if h is None:
            continue
        right, left, used = h
        if offsets:  # the trial's pelvis frame, once for both sides
            at = {c: t.markers[frames, t.labels.index(label)] for c, label in used.items()}
            mid = 0.5 * (at["RPSI"] + at["LPSI"]) if "RPSI" in at else at["SACR"]
            with np.errstate(invalid="ignore"):
                _, x, y, z, pw, pd = _pelvis_frame(at["RASI"], at["LASI"], mid)
        for side, point in (("r", right), ("l", left)):
            gaps[side].append(np.linalg.norm(C[:, k[side]] - point, axis=1))
            if offsets:
                dx, dy, dz = offsets[side][0]
                conv[side].append(np.linalg.norm(C[:, k[side]] - (point + x * dx * pd + y * dy * pw + z * dz * pw),
                                                 axis=1))
        widths.append(np.linalg.norm(C[:, k["r"]] - C[:, k["l"]], axis=1))
        asis.append(np.linalg.norm(t.markers[frames, t.labels.index(found["RASI"])]
                                   - t.markers[frames, t.labels.index(found["LASI"])], axis=1))
    if not widths:
        return {}
    with np.errstate(invalid="ignore"):
        width = (float(np.nanmedian(np.concatenate(widths))), float(np.nanmedian(np.concatenate(asis))))
        out = {}
        for side, g in gaps.items():
            if not np.isfinite(np.concatenate(g)).any():
                continue
            c = np.concatenate(conv[side]) if conv[side] else np.array([np.nan])
            own = offsets[side][1] if offsets else math.nan
            out[side] = (float(np.nanmedian(np.concatenate(g))), width,
                         float(np.nanmedian(c)) if np.isfinite(c).any() else math.nan, own)
        return out


def regression_hips(model: Model, trials: tuple[Trial, ...]) -> tuple[Model, tuple[Trial, ...], dict[str, str]]:
    """The model with a virtual marker at each hip centre (on the thigh's origin, where the hip is) and the trials
    with its Harrington position in every frame (NaN where a landmark is not seen; unseen in a trial that shows none
    of the model's markers, beside one that shows the landmarks); and the landmarks used (Plug-in Gait name -> the
    model's label).  The trials' labels must be the model's (calibrate maps them first).  One-line CalibrateError
    when the model lacks a hip or a landmark, or a trial lacks a landmark."""
    found = _pelvis_landmarks(model, trials)
    need = [c for c in ("RASI", "LASI") if c not in found]
    if not need and not ("RPSI" in found and "LPSI" in found or "SACR" in found):
        need = ["RPSI and LPSI, or SACR"]
    if need:
        raise CalibrateError(f"hip_regression: {model.path.name} has no marker for {', '.join(need)} (the pelvis "
                             "landmarks Harrington's regression needs); add them to the model or leave "
                             "hip_regression off")
    pelvis = model.markers[model.marker_index(found["RASI"])].segment
    hips = hip_joints(model, pelvis)
    if set(hips) != {"r", "l"}:
        raise CalibrateError(f"hip_regression: {model.path.name} has no left and right hip (ball joints named hip_l "
                             f"and hip_r below {pelvis}); leave hip_regression off")
    for name in VIRTUAL:
        if name in model.marker_names:
            raise CalibrateError(f"hip_regression: {model.path.name} already has a marker {name}; rename it")
    used: dict[str, str] = {}
    out = []
    known = set(model.marker_names)
    regressed = [_harrington_of(t, found) for t in trials]
    for t, h in zip(trials, regressed, strict=True):
        if h is None and any(r is not None for r in regressed) and not any(
                lab in known and np.isfinite(t.marker(lab)).any() for lab in t.labels):
            # A trial of clusters alone (a CAST protocol's walk beside its static): the virtual markers unseen there,
            # the hips placed by the trials with the landmarks.
            blank = np.full((t.n_frames, 1, 3), np.nan)
            out.append(replace(t, labels=t.labels + VIRTUAL, markers=np.concatenate([t.markers, blank, blank], axis=1)))
            continue
        if h is None:
            have = {c for c, label in found.items() if label in t.labels}
            missing = [found[c] for c in ("RASI", "LASI") if c not in have]
            if not ({"RPSI", "LPSI"} <= have or "SACR" in have):
                pair = " and ".join(found[c] for c in ("RPSI", "LPSI") if c in found)
                missing.append(" or ".join(x for x in (pair, found.get("SACR", "")) if x))
            raise CalibrateError(f"hip_regression: {t.source or 'a trial'} has no {', '.join(missing)} (the pelvis "
                                 "landmarks Harrington's regression needs); leave hip_regression off")
        right, left, read = h
        used.update(read)
        out.append(replace(t, labels=t.labels + VIRTUAL,
                           markers=np.concatenate([t.markers, right[:, None], left[:, None]], axis=1)))
    model = add_markers(model, {VIRTUAL[0]: (hips["r"].child, np.zeros(3)), VIRTUAL[1]: (hips["l"].child, np.zeros(3))})
    return model, tuple(out), used
