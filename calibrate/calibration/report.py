"""What a calibration tells its user: the report JSON, the stdout summary, and the output files.

Units at this edge: millimetres for positions and errors, degrees for axes, seconds for
time (the JSON says so in its key names).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import __version__
from ..errors import CalibrateError
from ..io.labels import UNLABELLED
from ..io.measurements import lateral_distance, lateral_markers_of
from ..io.motion import motion_csv_text
from ..io.outputs import check_targets, put_text, write_all
from ..model.model import Model, Parameters, hinge_axis
from ..model.urdf import mass_factor, urdf_text, with_comment
from ..problem.priors import on_axis_markers, placeholder_markers, symmetry_pairs
from ..seed.association import shared_clause
from ..seed.geometry import marker_rms
from ..software import software_versions
from .html import asymmetry_clause, left_out_clause, mirror_clause, report_html, seed_note_groups
from .identifiability import IDENTIFIED, NARROW_TURN, segment_end
from .moved import REPLACED_MIN
from .noise import NOISE_TAU_SECONDS, tau_cap
from .records import Identified, StillNote
from .regression import FUNCTIONAL_RANGE, REGRESSION_FAR, harrington_width, hip_joints
from .series import report_series

if TYPE_CHECKING:
    from .result import Calibration


def _mm(x: float) -> float:
    return round(1000.0 * float(x), 6)


def _list(a) -> list:
    return [None if not math.isfinite(float(v)) else round(float(v), 9) for v in np.ravel(a)]


def calibration_report(cal: Calibration) -> dict:
    """Plain, JSON-ready description of a Calibration."""
    model, st, s = cal.model, cal.settings, cal.summary
    per = cal.per_marker()
    kinds = {j.name: j.kind for j in model.joints}
    params = []
    for c in cal.changes:
        group = c.group
        unit = {"centre": "mm", "marker": "mm", "axis": "deg", "scale": "fraction"}[group]
        if group in ("centre", "marker"):
            base, value = [_mm(v) for v in c.base], [_mm(v) for v in c.value]
        else:
            base, value = _list(c.base), _list(c.value)
        entry = {"name": c.name, "group": group, "unit": unit, "base": base, "value": value,
                 "change": round(c.change, 6), "std": _list(c.std), "identified": c.identified}
        if group in ("centre", "marker"):
            entry["beyond_scale"] = round(c.beyond_scale, 6)
        if c.unreliable:
            entry["unreliable"] = True
        if group == "centre":
            entry["kind"] = kinds[c.item]
        if c.note:
            entry["note"] = c.note
        params.append(entry)
    trials = []
    for i, t in enumerate(cal.trials):
        res = cal.residuals[cal.trial_frames(i)]
        err = np.linalg.norm(res, axis=2)
        entry = {"source": t.source, "frames": t.n_frames, "rate_hz": t.rate, "first_frame": t.first_frame,
                 "times_s": [round(float(t.times[0]), 6), round(float(t.times[-1]), 6)] if t.n_frames else None,
                 "rms_mm": _mm(marker_rms(res)), "max_mm": _mm(np.nanmax(err)) if np.isfinite(err).any() else None,
                 "outliers": sum(1 for o in cal.outliers if o.trial == i)}
        if cal.trial_weights and cal.trial_weights[i] < t.n_frames:  # a still trial counted as a few frames
            entry["counted_as_frames"] = cal.trial_weights[i]
        if i < len(cal.label_maps) and cal.label_maps[i] is not None:
            entry["labels"] = cal.label_maps[i].to_json()
        trials.append(entry)
    per_outlier: dict[str, int] = {}
    for o in cal.outliers:
        per_outlier[o.marker] = per_outlier.get(o.marker, 0) + 1
    return {
        "calibrate_version": __version__,
        "software": software_versions(),  # Python's and the libraries' versions too: what reproduces the result
        "trials": trials,
        "marker_set": {
            "used": [n for n in model.marker_names if n not in cal.unused_markers],
            "new": [{"label": m.label, "segment": m.segment, "position_mm": [_mm(v) for v in m.position],
                     "reason": m.reason, **({"check": m.check} if m.check else {}),
                     **({"declared": True} if m.declared else {}), **({"past_joint": True} if m.past else {})}
                    for m in cal.new_markers if m.segment is not None],
            "left_out": [{"label": m.label, "reason": m.reason, "sits_by": list(m.sits_by)}
                         for m in cal.new_markers if m.segment is None],
            "ignored_labels": list(cal.ignored_labels), "unused_model_markers": list(cal.unused_markers)},
        "outliers": {"count": len(cal.outliers), "per_marker": per_outlier,
                     "threshold_noise_sd": st.outliers,
                     "rejected": [{"trial": o.trial, "frame": o.frame, "marker": o.marker, "error_mm": _mm(o.error),
                                   **({"before_solve": True} if o.before else {})}
                                  for o in cal.outliers[:200]]},
        "model": {"source": str(model.path), "segments": len(model.segments), "joints": len(model.joints),
                  "dof": model.nz, "markers": len(model.markers),
                  "new_markers": sum(1 for m in cal.new_markers if m.segment is not None)},
        "mass": _mass(cal),
        "measurements": measurements_table(cal),
        "lateral_sides": lateral_sides(cal),
        "settings": {"free": list(st.free), "noise_mm": 1000 * st.noise, "loss": st.loss,
                     "loss_scale": st.loss_scale,
                     "priors": {"marker_mm": 1000 * st.priors.marker, "centre_mm": 1000 * st.priors.centre,
                                "axis_deg": math.degrees(st.priors.axis), "scale": st.priors.scale,
                                "size": st.priors.size,
                                "symmetry_scale": st.priors.symmetry_scale,
                                "symmetry_centre_mm": 1000 * st.priors.symmetry_centre,
                                "width_mm": 1000 * st.priors.width,
                                "population_width_mm": 1000 * st.priors.population_width,
                                "on_axis_mm": 1000 * st.priors.on_axis,
                                "pair_axis_deg": math.degrees(st.priors.pair_axis),
                                "knee_landmark_mm": 1000 * st.priors.knee_landmark,
                                "ankle_landmark_mm": 1000 * st.priors.ankle_landmark,
                                "joint_marker_mm": 1000 * st.priors.joint_marker,
                                "held_centre_mm": 1000 * st.priors.held_centre,
                                "placeholder_mm": 1000 * st.priors.placeholder},
                     "lateral_markers": [{"joint": j, "marker": mk, "distance_mm": 1000 * d}
                                         for j, mk, d in st.lateral_markers],
                     "learn_noise": st.learns_noise,
                     "max_iterations": st.max_iterations, "ftol": st.ftol, "xtol": st.xtol, "gtol": st.gtol,
                     "seed": st.seed, "new_markers": st.new_markers, "outlier_sigmas": st.outliers,
                     "marker_noise_mm": {k: 1000 * v for k, v in st.marker_noise},
                     "lock_deg": {k: math.degrees(v) for k, v in st.lock}, "hold_axes": list(st.hold_axes),
                     "segment_frames": st.segment_frames,
                     "hold_segments": list(st.hold_segments), "hold_centres": list(st.hold_centres),
                     "auto_hold": st.auto_hold, "moved_markers": st.moved_markers, "far_joints": st.far_joints,
                     "hip_regression": st.hip_regression, "compiled": cal.compiled},
        "held_axes": list(cal.held_axes),
        "narrow_axes_deg": {n: math.degrees(t) for n, t in cal.narrow_axes},
        # an OpenSim model's gimbals (calibrate.io.osim_info.with_gimbals): hinges about one centre through phantom
        # bodies, one ball in the source's angle convention, their axes held
        "gimbal_axes": _gimbal_axes(cal),
        "narrow_centres_deg": {n: math.degrees(t) for n, t in cal.narrow_centres},
        "cluster_centres": list(cal.cluster_centres),
        "on_axis_markers": on_axis_labels(cal),
        "axis_pairs": axis_pair_table(cal),
        "pair_centres": pair_centre_table(cal),
        "landmarks": landmark_table(cal),
        "population_widths": population_width_table(cal),
        "auto_locked": [{"coordinate": lk.coordinate, "value_deg": math.degrees(lk.value), "segment": lk.bare,
                         "neighbours": list(lk.neighbours), "spread_deg": math.degrees(lk.spread),
                         "per_frame_deg": math.degrees(lk.per_frame),
                         "neighbour_per_frame_deg": [math.degrees(v) for v in lk.neighbour_per_frame],
                         "turned_deg": math.degrees(lk.turned), "note": lk.text()} for lk in cal.auto_locked],
        "unresolved": [u.to_json() for u in cal.unresolved],
        "unplaced_in_trial": [{"trial": i, "segments": [u.to_json() for u in us], "held": i in cal.unplaced_held}
                              for i, us in cal.unplaced_in_trial],
        # frames (0-based, in the trial) whose markers do not place the root: their poses bridged
        "unplaced_frames": [{"trial": i, "frames": list(fs), "runs": [list(r) for r in frame_runs(fs)]}
                            for i, fs in enumerate(cal.unplaced_frames) if fs],
        "implausible": [b.to_json() for b in cal.implausible],
        "suspect_labels": [{"trial": cal.trials[i].source or f"trial {i + 1}", "label": m.label, "segment": m.segment,
                            "moves_with": m.rides_with, "segment_labels": list(m.partners),
                            "exchanges": [list(x) for x in m.exchanges],
                            "distance_sd_own_mm": 1e3 * m.sd_own,
                            "distance_sd_other_mm": 1e3 * m.sd_other} for i, m in cal.misplaced],
        # markers whose positions scatter as white noise from frame to frame (calibrate.seed.jitter): left out there
        "jittery_markers": [{"trial": cal.trials[i].source or f"trial {i + 1}", **x.to_json()} for i, x in cal.jittery],
        "exchanged_back": [{"trial": cal.trials[i].source or f"trial {i + 1}", **x.to_json()}
                           for i, x in cal.exchanged_back],
        "trials_apart": [{"trials": [cal.trials[k].source or f"trial {k + 1}" for k in (i, j)],
                          "segment_distances_apart": misfit, "pairs": pairs}
                         for i, j, misfit, pairs in cal.trials_apart],
        # two moving trials that put markers far apart on their segments (moved.places_apart): the pairs, the markers
        "places_apart": [x.to_json([_trial_name(cal, k) for k in range(len(cal.trials))]) for x in cal.places_apart],
        # two labels of one segment exchanged between two trials, or against the base model in trials that have them
        # alike (calibrate.seed.association.exchanged_between)
        "exchanged_labels": [{"labels": list(x.labels), "segment": x.segment,
                              "trials": [_trial_name(cal, k) for k in x.trials],
                              "kept_mm": 1e3 * x.kept, "exchanged_mm": 1e3 * x.exchanged,
                              "references": list(x.references),
                              "odd_trial": None if x.odd is None else _trial_name(cal, x.odd),
                              "against_model": x.against_model,
                              # the lab's protocol taken: the base model's places of the two exchanged for the fit
                              "protocol": x.protocol,
                              "note": x.text([_trial_name(cal, k) for k in range(len(cal.trials))])}
                             for x in cal.exchanged],
        # markers a still trial showed elsewhere on their segment than the moving trials (Settings.moved_markers):
        # their positions there left out, the model keeping the moving trials' place
        "moved_markers": [{**m.to_json(), "trial": cal.trials[m.trial].source or f"trial {m.trial + 1}"}
                          for m in cal.moved],
        # a still trial's cluster labels read as the moving trials name them (calibrate.calibration.moved.
        # exchanged_clusters): each label's data there taken as the label it is read as
        "relabelled": [{**x.to_json(), "trial": _trial_name(cal, x.trial),
                        **({"reference": _trial_name(cal, x.reference)} if x.reference >= 0 else {})}
                       for x in cal.relabelled],
        # the same, found with the option off: their positions kept in the fit (--moved-markers leaves them out)
        "moved_markers_kept": [{**m.to_json(), "trial": cal.trials[m.trial].source or f"trial {m.trial + 1}"}
                               for m in cal.moved_kept],
        # every trial still (a static alone): the largest relative marker motion of the trials (mm), else null
        "still_only_mm": None if cal.still_only is None else 1e3 * cal.still_only,
        "still_centres": list(cal.still_centres),
        # joints a still trial held where the moving trials never go (Settings.far_joints): its positions of the
        # markers beyond them left out of the fit, its angles there fitted to them afterwards
        "far_joints": [{**f.to_json(), "trial": cal.trials[f.trial].source or f"trial {f.trial + 1}"}
                       for f in cal.far_joints],
        # markers at a joint centre (points the lab computed there, e.g. R_HJC): kept at their offsets from the
        # centres within settings.priors.joint_marker_mm, so that the trials' positions of them place the centres
        "joint_centre_markers": [m.to_json() for m in cal.joint_markers],
        "placeholder_markers": _placeholders(cal),
        # how far the trials turn each hip, and whether that places its centre (calibrate.calibration.regression)
        "hip_motion": [h.to_json() for h in cal.hip_motion],
        # settings.hip_regression "auto": "applied: ..." (the hips the calibration without it left implausible, and
        # so calibrated again with it), "not applied: ..." (the regression could not run), "" (nothing implausible)
        "hip_regression_auto": cal.hip_regression_auto,
        # Plug-in Gait's knee axes (its femur bones' lateral axes, in trials that carry its bones) against the axis
        # its own tibia turns about in its femur, and the calibrated knees' (calibrate.calibration.plugin_gait)
        "plugin_gait_knees": [k.to_json() for k in cal.knee_axes],
        "model_outputs_ignored": sorted(set().union(*(t.model_outputs for t in cal.trials))),
        "noise": {"learnt": cal.noise_learnt, "per_marker_mm": {k: _mm(v) for k, v in cal.noise.items()},
                  "weight_sd_mm": {k: _mm(v) for k, v in cal.noise_weight.items()},
                  # the longest correlation time a marker's residuals counted for on every frame (its weight's SD
                  # is at most its SD times the square root of this many frames)
                  "correlation_cap_s": NOISE_TAU_SECONDS,
                  "correlation_cap_frames": tau_cap(np.array([t.rate for t in cal.trials]),
                                                    np.array([t.n_frames for t in cal.trials]))},
        "symmetry": symmetry_table(cal),
        "static_pose": static_pose_table(cal),
        "neutral_trial": None if cal.neutral is None else (cal.trials[cal.neutral].source or cal.neutral),
        "not_neutral": [{"joint": j, "mean_deg": math.degrees(a)} for j, a in cal.not_neutral],
        "neutral_pose_deg": None if cal.pose is None else {n: math.degrees(v) for n, v in cal.pose},
        "neutral_pose_not_set": list(cal.pose_unset),
        "markers": {"rms_mm": _mm(cal.marker_rms), "max_mm": _mm(cal.marker_max),
                    "initial_rms_mm": _mm(marker_rms(cal.initial_residuals)),
                    "per_marker": {n: {"rms_mm": _mm(r), "max_mm": _mm(m), "frames": f}
                                   for n, (r, m, f) in per.items()}},
        "solver": {"iterations": s.iterations, "accepted_steps": s.accepted, "initial_cost": s.initial_cost,
                   "final_cost": s.final_cost, "cost_history": list(s.cost_history),
                   "termination": s.termination, "converged": s.converged,
                   "linearize_s": s.linearize_seconds, "linear_solver_s": s.linear_solver_seconds,
                   "rounds": (s.coarse or s).rounds,
                   "coarse": None if s.coarse is None else {
                       "frames": s.coarse_frames, "iterations": s.coarse.iterations,
                       "initial_cost": s.coarse.initial_cost, "final_cost": s.coarse.final_cost,
                       "cost_history": list(s.coarse.cost_history), "termination": s.coarse.termination},
                   "levels": [{"frames": f, "iterations": i} for f, i in s.levels]},
        "seed": {"notes": list(cal.seed.notes), "taken": cal.seed.taken,
                 "joints": {j.name: {"method": j.method, "ok": j.ok} for j in cal.seed.joints}
                 if cal.seed.joints is not None else {}},
        "parameters": params,
        "subject_size": subject_size(cal),
        "unidentified": [c.name for c in cal.changes if not c.identified],
        "unreliable": [c.name for c in cal.changes if c.unreliable],
        # every result the summary calls implausible (a scale, a centre, an axis, the hips, a static's left against
        # right, a lateral marker against a measured width), as its `implausible` lines say it
        "implausible_flags": implausible_flags(cal),
        "notes": list(cal.notes),
        "times_s": {k: round(v, 6) for k, v in cal.times.items()},
        "series": report_series(cal),
    }


IMPLAUSIBLE = "  implausible  "  # how the summary starts a line that calls a result implausible


def implausible_flags(cal: Calibration) -> list[str]:
    """The summary's `implausible` lines (summary_text), each without its tag: every result the calibration found
    against anatomy or the subject's measurements (a segment's scale, a centre or axis carried far by a trade the
    data do not separate, hips outside the pelvis or far from Harrington's regression, a static's left against its
    right, a lateral marker against a measured width) -- what a lab's batch of subjects is sorted by
    (calibrate.calibration.batch's `implausible` column)."""
    return [line[len(IMPLAUSIBLE):] for line in summary_text(cal).splitlines() if line.startswith(IMPLAUSIBLE)]


def report_locks(report: dict, elsewhere: bool = False) -> dict[str, float]:
    """The coordinates a calibration held in every frame (rad or m), from its report JSON (``calibration_report``):
    its settings' ``lock_deg`` and its ``auto_locked`` hinges; Calibration.locked of the run that wrote it.
    `elsewhere`: what a fit of other trials holds (Calibration.locked_elsewhere: after a static alone,
    ``still_only_mm``, the settings' locks only).  ValueError, TypeError or KeyError where the report is not as
    calibrate writes it."""
    settings = report.get("settings") or {}

    def angle(name: str, deg: object) -> float:
        if isinstance(deg, bool) or not isinstance(deg, (int, float)) or not math.isfinite(deg):
            raise ValueError(f"{name}'s lock is {deg!r}, not an angle in degrees")
        return math.radians(deg)

    locked = {k: angle(k, v) for k, v in (settings.get("lock_deg") or {}).items()}
    auto = {x["coordinate"]: angle(x["coordinate"], x["value_deg"]) for x in report.get("auto_locked") or []}
    if elsewhere and report.get("still_only_mm") is not None:  # the settings carry the auto-locks too
        return {k: v for k, v in locked.items() if k not in auto}
    return {**locked, **auto}


def _mass(cal) -> dict:
    """Segment masses written to the subject URDF: the base model's, scaled to the subject's mass if given
    (or measured: the trial's subject measurements)."""
    k = mass_factor(cal.model, cal.mass)
    return {"subject_kg": cal.mass, "from": cal.mass_from, "base_kg": cal.model.total_mass, "factor": k,
            "segments_kg": {sg.name: round(k * sg.mass, 6) for sg in cal.model.segments if sg.mass > 0}}


# A lateral marker further than this (m) along the axis from where the joint's measured width puts it is flagged
# (the summary's `implausible` lines, the report's measurements.lateral_mm.*.flagged): a caliper and a marker
# placed by a clinician agree to a few mm.  pig_walk (2026-11-27): knees 4-5 mm, ankles 5-7 mm with the widths
# used; its elbows 47 and 66 mm (not used).
#: A calibration whose markers fit worse than this (RMS over every marker position of every frame, m) is called
#: implausible: real trials calibrate to 2-11 mm (the public sweep's 31 files on models/human.urdf 0.3-7.2 mm, 38 on
#: Rajagopal2016.osim 0.3-7.4 mm but six; issue 17's runs 7.3-10.2 mm: docs/benchmarks.md), and those six, c3d.org's
#: sample02 (a cluster set whose thigh labels RTH1-3 happen to be Rajagopal2016's own), ended at 32 mm, its forearm's
#: cluster put on the pelvis.
POOR_FIT = 0.020


def poor_fit_line(cal: Calibration) -> str | None:
    """The summary's `implausible` line of a calibration that fits its markers worse than POOR_FIT, naming the
    markers it fits worst (their trial labels: what to check first); None where it fits them better."""
    rms = cal.marker_rms
    if not rms > POOR_FIT:
        return None
    label = {m.label: m.trial_label for mapping in cal.label_maps for m in mapping}
    worst = sorted(((r, n) for n, (r, _, seen) in cal.per_marker().items() if seen), reverse=True)[:6]
    named = ", ".join(f"{label.get(n, n)} {1e3 * r:.0f}" for r, n in worst)
    return (f"the markers fit to {1e3 * rms:.1f} mm RMS, where real trials calibrate to 2-11 mm: the trials' labels "
            f"and the model's markers may not name the same points (worst, mm RMS: {named}); check them (`calibrate "
            "inspect TRIAL --model MODEL`) or name them with --markers map.toml")


#: A leg whose thigh (hip centre to knee centre) is more than LEG_RATIO times its shank (knee centre to ankle
#: centre), or less than its inverse, is implausible: adults' are about equal (Winter, after Drillis & Contini:
#: 0.245 and 0.246 of the stature), Plug-in Gait's own centres on pig_walk 1.11-1.19, the public sweep's real runs
#: 0.88-1.27 on models/human.urdf and Rajagopal2016.osim; pyCGM2's ball-knee OpenSim models on pig_walk, whose
#: knees the walk carried down the shank, 1.31-1.76 (docs/benchmarks.md).
LEG_RATIO = 1.35


def leg_proportion_lines(cal: Calibration) -> list[str]:
    """The summary's `implausible` lines (without the tag) of legs whose thigh and shank lengths between the
    calibrated hip, knee and ankle centres are further apart than LEG_RATIO: a knee centre carried along the leg."""
    model, p = cal.model, cal.params
    out = []
    for _, hip in sorted(hip_joints(model).items(), key=lambda kv: kv[0] != "r"):
        femur = model.segment_index(hip.child)
        knee = segment_end(model, femur)
        if knee is None:
            continue
        tibia = model.segment_index(model.joints[knee].child)
        ankle = segment_end(model, tibia)
        if ankle is None:
            continue
        thigh = float(np.linalg.norm(p.scale[femur] * p.centre[knee]))
        shank = float(np.linalg.norm(p.scale[tibia] * p.centre[ankle]))
        if not (shank > 0 and thigh > 0) or 1.0 / LEG_RATIO <= thigh / shank <= LEG_RATIO:
            continue
        out.append(f"{model.joints[knee].name}: hip to knee {1e3 * thigh:.0f} mm, knee to ankle {1e3 * shank:.0f} mm "
                   f"({thigh / shank:.2f} times), where adults' are about equal (Winter's proportions; real "
                   f"calibrations 0.88-1.27): the knee centre was carried along the leg, which the trials' markers "
                   "do not hold (a ball knee's extra turns take up the skin's motion); the lab's knee centres as "
                   "markers (a marker map naming them) or a hinge knee hold it")
    return out


MEASURED_TOLERANCE = 0.020


def _base_on_subject(cal) -> Parameters:
    """The base model's geometry on the subject model's markers (what a lateral marker's side is counted against)."""
    model = cal.model
    origin = cal.base_model or model
    base = origin.parameters()
    if origin is not model:
        # New markers sit among the base model's on their segments (the subject's markers go segment by segment):
        # each marker's base place by its name, a new one's its own calibrated place.  By index, the new markers on
        # the pelvis shifted every lateral marker after them, and BTKData's FunctionalWalk read its knees and ankles
        # 37-47 mm on the wrong side of their centres.
        base = Parameters(base.scale, base.centre, base.axis, np.array(
            [base.marker[origin.marker_index(name)] if name in origin.marker_names else cal.params.marker[k]
             for k, name in enumerate(model.marker_names)]))
    return base


def lateral_sides(cal) -> dict[str, dict]:
    """Each knee, ankle and elbow with its Plug-in Gait lateral marker (KNE, ANK, ELB) that the trials show: the
    marker's distance from the calibrated centre along the hinge axis, counted towards the side the base model has
    it on (mm), and whether it ended on the other side (`medial`).  A marker on the lateral epicondyle or
    malleolus sits half the joint's width and its own radius lateral of the centre, some 20 mm or more on any
    subject: one medial of it is a centre and marker that traded along the axis, which no motion places, or a
    label that names another point (the report's `lateral_sides`; the summary's `implausible` line)."""
    model = cal.model
    base = _base_on_subject(cal)
    out = {}
    for name, marker in lateral_markers_of(model):
        if marker in cal.unused_markers:
            continue
        d = lateral_distance(model, cal.params, base, name, marker)
        out[name] = {"marker": marker, "lateral_mm": 1000 * d, "medial": d < LATERAL_SIDE}
    return out


# A lateral marker (Plug-in Gait's KNE, ANK, ELB) whose distance from its hinge centre along the axis, counted towards
# the lateral side, ends below this (m) is flagged: it lies medial of the centre.  Measured (2026-12-05) on the 13 real
# runs on models/human.urdf and its girdle: 72 of 76 lateral markers 3-75 mm lateral; Rajagopal's walk's LELB 35 mm
# medial of the elbow (its static's arms left out: centre and marker traded along the axis), and the OpenCap test
# set's L_ankle 5-12 mm medial on its three trials (19 mm from the tibia's axis, where a lateral malleolus sits 35-45
# mm: the shank's frame and the marker traded, or the label, read as LANK, names another point).  Those at 3-14 mm
# (pig_walk's RELB, stairdown's ankles) are not anatomy either, but unflagged: the line is for a marker on the wrong
# side.
LATERAL_SIDE = 0.0


def measurements_table(cal) -> dict | None:
    """The trials' subject measurements (calibrate.io.measurements) and, for each knee, ankle and elbow with its
    lateral marker, that marker's distance from the calibrated centre along the hinge axis against the
    measured one (half the width plus the marker's radius), and whether the measurement placed the centre
    (Settings.lateral_markers)."""
    m = cal.measurements
    used = {(j, mk): d for j, mk, d in cal.settings.lateral_markers}
    if m is None and not used:
        return None
    model = cal.model
    base = _base_on_subject(cal)
    lateral = {}
    for name, marker in lateral_markers_of(model):
        measured = used.get((name, marker), None if m is None else m.lateral_distance(name))
        if measured is None or marker in cal.unused_markers:  # (a marker no trial shows: an upper-body trial's knees)
            continue
        calibrated = lateral_distance(model, cal.params, base, name, marker)
        lateral[name] = {"marker": marker, "measured_mm": 1000 * measured, "calibrated_mm": 1000 * calibrated,
                         "used": (name, marker) in used,
                         "flagged": abs(calibrated - measured) > MEASURED_TOLERANCE}
    out = m.as_dict() if m is not None else {"source": "settings (lateral_markers)"}
    out["lateral_mm"] = lateral
    out["width_prior_mm"] = 1000 * cal.settings.priors.width
    return out


def _measurement_lines(cal) -> list[str]:
    """The summary's lines on the subject measurements: what was read, and each lateral marker's distance
    from its joint centre along the axis, calibrated against measured."""
    t = measurements_table(cal)
    if t is None:
        return []
    what = [f"height {t['height_mm'] / 1000:g} m" if t.get("height_mm") else "",
            f"mass {t['mass_kg']:g} kg" if t.get("mass_kg") else ""]
    out = [f"  measured     {t['source']}" + (": " + ", ".join(w for w in what if w) if any(what) else "")]
    lat = t["lateral_mm"]
    if lat:
        pairs = [f"{j} {v['calibrated_mm']:.0f}/{v['measured_mm']:.0f}" + ("" if v["used"] else " (not used)")
                 for j, v in lat.items()]
        out.append(f"  {'':13s}lateral marker to joint centre along the axis, calibrated / measured (mm): "
                   + ", ".join(pairs))
    for j, v in lat.items():
        if v["flagged"]:
            out.append(f"{IMPLAUSIBLE}{j}: {v['marker']} {v['calibrated_mm']:.0f} mm from the centre along the axis, "
                       f"the measured width puts it {v['measured_mm']:.0f} mm lateral"
                       + ("" if v["used"] else " (the width was not used; docs/calibration.md, subject measurements)"))
    return out


def _lateral_side_lines(cal) -> list[str]:
    """The summary's `implausible` lines of lateral markers ended medial of their hinge centre (lateral_sides), but
    for a joint the measured width flags already."""
    t = measurements_table(cal)
    measured = {j for j, v in (t or {}).get("lateral_mm", {}).items() if v["flagged"]}
    # The trials' own labels that became the marker (an alias: Rajagopal's L.Elbow read as LELB)
    given: dict[str, list[str]] = {}
    for labels in cal.label_maps:
        for trial_label, label in (labels.renamed.items() if labels is not None else ()):
            if trial_label != label and trial_label not in given.setdefault(label, []):
                given[label].append(trial_label)
    return [f"{IMPLAUSIBLE}{j}: {v['marker']}"
            + (f" (the trials' {', '.join(given[v['marker']])})" if given.get(v["marker"]) else "")
            + f" ends {-v['lateral_mm']:.0f} mm medial of the centre along the axis, where a lateral epicondyle's or "
            "malleolus's marker sits lateral of it: the centre and the marker traded along the axis, which no motion "
            "places, or the label names another point (check it; --markers map.toml maps it)" + _across_bare(cal, j)
            for j, v in lateral_sides(cal).items() if v["medial"] and j not in measured]


def _across_bare(cal, joint: str) -> str:
    """The lateral-side line's clause for a hinge whose child carries no marker the trials show and turns on through a
    free hinge of its own (the ankle and the subtalar across the talus): the two trade, and the neighbour held places
    the first.  On the OpenCap test set's walk, drop jump and walk on the girdle model the ankles' lateral markers
    ended 5-12 mm medial of their centres; with --lock subtalar_l,subtalar_r 36-42 mm lateral, the marker fit 0.4-1.4
    mm worse (the subtalar's own turn is then the ankle's or the markers')."""
    model = cal.model
    jt = model.joints[model.joint_index(joint)]
    if any(m.segment == jt.child and m.name not in cal.unused_markers for m in model.markers):
        return ""
    held = cal.locked
    beyond = [k for k in model.joints if k.parent == jt.child and k.kind == "hinge" and k.dofs[0] not in held]
    if not beyond:
        return ""
    names = ", ".join(k.dofs[0] for k in beyond)
    return (f"; {joint} and {', '.join(k.name for k in beyond)} trade across {jt.child}, which carries no marker the "
            f"trials show: --lock {names} holds the one, at some cost to the fit where it turned")


def _gimbal_axes(cal) -> list[dict]:
    """The gimbals whose axes the calibration held: their coordinates (held) and the phantom bodies between."""
    if "<opensim" not in cal.model.text:
        return []
    from ..io.osim_info import osim_info

    info = osim_info(cal.model)
    held = set(cal.settings.hold_axes)
    return [{"coordinates": [c for c in coords if c in held], "bodies": list(bodies)}
            for coords, bodies in (info.gimbals if info is not None else ()) if held & set(coords)]


def _held_why(cal) -> list[str]:
    """Why calibrate held the axes it held (the summary's `axes held` line): the joints the trial does not show
    moving, and those the moving trials turn too little to place their axis against the skin (narrow_axes)."""
    from ..io.osim_info import gimbal_text, osim_info

    narrow = dict(cal.narrow_axes)
    quiet = [n for n in cal.held_axes if n not in narrow]
    gimbal = gimbal_text(osim_info(cal.model), cal.settings.hold_axes) if "<opensim" in cal.model.text else ""
    return ([f"; the trial does not show {', '.join(quiet)} moving"] if quiet else []) + (
        [f"; the moving trials turn {', '.join(f'{n} through {math.degrees(t):.0f} deg' for n, t in narrow.items())}"
         " only: too little to place an axis against the skin's turn of the segments (up to 4.4 deg in a walk)"]
        if narrow else []) + ([f"; {gimbal} (--no-auto-hold frees them)"] if gimbal else [])


def frame_runs(frames) -> list[tuple[int, int]]:
    """Consecutive runs (first, last) of sorted frame indices."""
    runs: list[tuple[int, int]] = []
    for f in frames:
        if runs and f == runs[-1][1] + 1:
            runs[-1] = (runs[-1][0], f)
        else:
            runs.append((f, f))
    return runs


def runs_text(frames=(), runs=None) -> str:
    """Sorted frame indices (or their `runs`, frame_runs') as text: '0-4, 222-280' (the first six runs, then how many
    more)."""
    runs = frame_runs(frames) if runs is None else runs
    text = ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs[:6])
    return text + (f" and {len(runs) - 6} more runs" if len(runs) > 6 else "")


def _trial_name(cal, k: int) -> str:
    """Trial k's file (or 'trial k+1' for one read from memory)."""
    return cal.trials[k].source or f"trial {k + 1}"


def symmetry_table(cal) -> dict:
    """Left/right differences of the result: per segment pair the scale difference (fraction of their
    mean) and the length difference of the segments that carry a joint centre below them (mm, %; with the
    difference's posterior SD, the priors' alone and whether the trials measure it, where the calibration has
    them: Calibration.length_sd), per joint pair the distance between the left centre and the mirrored right
    one (mm, at the subject's scale; its SDs alike in centre_mirror_sd: Calibration.mirror_sd); the largest of
    each, and the symmetry prior's SDs."""
    model, p = cal.model, cal.params
    segs, joints, mirror = symmetry_pairs(model, model.parameters().centre)
    scale = {}
    for a, b in segs:
        sa, sb = float(p.scale[a]), float(p.scale[b])
        scale[f"{model.segments[a].name[:-2]}"] = round(abs(sa - sb) / (0.5 * (sa + sb)), 6)
    length = {}
    for a, b in segs:
        ja, jb = segment_end(model, a), segment_end(model, b)
        if ja is None or jb is None:
            continue
        la, lb = (float(np.linalg.norm(p.scale[s] * p.centre[j])) for s, j in ((a, ja), (b, jb)))
        if la > 0.05:
            name = model.segments[a].name[:-2]
            row = length[name] = {"left_mm": _mm(la), "right_mm": _mm(lb),
                                  "difference": round(abs(la - lb) / (0.5 * (la + lb)), 6)}
            if name in cal.length_sd:  # the difference's posterior SD, the priors' alone, and whether it is measured
                sd, sd0 = cal.length_sd[name]
                row.update(difference_sd_mm=_mm(sd), priors_sd_mm=_mm(sd0), measured=bool(sd <= IDENTIFIED * sd0))
            elif cal.length_sd:  # both ends held at the base model's (Settings.hold_segments): not the subject's
                row["held"] = True
    centre = {}
    for a, b in joints:
        sa = p.scale[model.segment_index(model.joints[a].parent)]
        sb = p.scale[model.segment_index(model.joints[b].parent)]
        centre[model.joints[a].name[:-2]] = _mm(float(np.linalg.norm(sa * p.centre[a] - mirror * sb * p.centre[b])))
    centre_sd = {name: {"sd_mm": _mm(sd), "priors_sd_mm": _mm(sd0), "measured": bool(sd <= IDENTIFIED * sd0)}
                 for name, (sd, sd0) in cal.mirror_sd.items() if name in centre}
    st = cal.settings.priors
    return {"prior": {"scale": st.symmetry_scale, "centre_mm": 1000 * st.symmetry_centre},
            "scale_difference": scale, "segment_length": length, "centre_mirror_mm": centre,
            "centre_mirror_sd": centre_sd,
            "largest_scale_difference": max(scale.values(), default=None),
            "largest_length_difference": max((v["difference"] for v in length.values()), default=None),
            "largest_centre_mirror_mm": max(centre.values(), default=None)}


def _foot_hint(cal, joints: list[str]) -> str:
    """What to do when a flagged static ankle or subtalar sits under a foot whose segment carries two markers
    or fewer and whose subtalar joints are free: lock them, as OpenSim's gait models do.  On pig_walk (HEE and TOE
    on each foot) the locked subtalars hold the static ankles at 1.9 / -3.5 deg against -35.6 / -5.8 free
    (docs/benchmarks.md); auto_hold locks them by itself (identifiability.trading_locks), so this is said when
    it is off or the trials showed them turning."""
    if not {"ankle", "subtalar"} & set(joints):
        return ""
    model, locked = cal.model, {n for n, _ in cal.settings.lock}
    free = [d for d in ("subtalar_l", "subtalar_r") if d in model.dof_names and d not in locked]
    used = set(model.marker_names) - set(cal.unused_markers)
    feet = [s for s in model.segments if s.name in ("calcn_l", "calcn_r")]
    if not free or not feet or any(sum(m in used for m in s.markers) > 2 for s in feet):
        return ""
    return (f"; the feet carry two markers each, which leave the subtalar joints to the priors: --lock "
            f"{','.join(free)} holds them at 0, as OpenSim's gait models do")


def _one_side_hint(cal, turned) -> str:
    """What to do when a flagged static pair's axis was held (or its angle locked) on one side only: the two sides'
    segment frames are then placed unalike.  Expert1's static forearms on models/human.urdf (radioulnar_l's axis held
    for its narrow turn, radioulnar_r's free) sat 113 deg apart, 25 with both held from the first solve; gait2392's
    (radioulnar_r locked, radioulnar_l free) 105 apart, within 20 with both held (docs/benchmarks.md, "A forearm's
    pronation decided by its markers' priors alone")."""
    held = set(cal.settings.hold_axes) | {n for n, _ in cal.settings.lock}
    # (a foot's pair: _foot_hint's lock, as OpenSim's gait models hold the subtalar)
    pairs = [(h.left, h.right) for h in turned
             if h.joint not in ("ankle", "subtalar") and (h.left in held) != (h.right in held)]
    if not pairs:
        return ""
    parts = []
    for a, b in pairs:
        one, other = (a, b) if a in held else (b, a)
        parts.append(f"{one}'s axis held, {other}'s free" if one in cal.settings.hold_axes
                     else f"{one} locked, {other}'s axis free")
    return (f"; {', '.join(parts)}: held on one side only, the two sides' frames are placed unalike; --hold-axes "
            f"{','.join(x for pair in pairs for x in pair)} holds both at the base model's from the first solve")


def static_pose_table(cal) -> dict:
    """Left/right hinge angles in the static trials (calibrate.calibration.result.static_hinges; degrees)
    and the pairs further apart than STATIC_ASYMMETRY_DEG (Calibration.static_asymmetry)."""
    from .result import STATIC_ASYMMETRY_DEG, static_hinges, static_trials

    def row(h) -> dict:
        return {"trial": cal.trials[h.trial].source or f"trial {h.trial + 1}", "joint": h.joint, **h.to_json()}

    hinges = static_hinges(cal.model, cal.motions, cal.neutral)
    return {"threshold_deg": STATIC_ASYMMETRY_DEG,
            "trials": [cal.trials[i].source or f"trial {i + 1}" for i in static_trials(cal.model, cal.motions,
                                                                                       cal.neutral)],
            "hinges": [row(h) for h in hinges],
            "flagged": [row(h) for h in hinges if h.flagged],
            "advice": (_foot_hint(cal, [h.joint for h in hinges if h.flagged])
                       + _one_side_hint(cal, [h for h in hinges if h.flagged])).lstrip("; ")}


def subject_size(cal) -> float | None:
    """The subject's size against the base model's: the mean scale of the segments whose scale was estimated (the
    centre of their scale priors, Priors.size); None when no scale was estimated."""
    est = [float(c.value[0]) for c in cal.changes if c.group == "scale" and np.isfinite(c.std).all()]
    return float(np.mean(est)) if est else None


def _scale_lines(cal) -> list[str]:
    """The segment scale factors, three to a line, with their posterior SDs: what OpenSim's Scale tool reports."""
    size = subject_size(cal)
    if size is None:  # no scale estimated
        return []
    cells = []
    for c in (c for c in cal.changes if c.group == "scale"):
        if not np.isfinite(c.std).all():
            cells.append(f"{c.item:14s}{c.value[0]:6.3f}{'  (held)':17s}")  # as wide as a cell with its SD
        else:
            flag = "  (prior)" if not c.identified else "         "
            cells.append(f"{c.item:14s}{c.value[0]:6.3f} +-{float(c.std[0]):5.3f}{flag}")
    lines = [f"  segment scales (x the base model's) +- posterior std; the subject's size {size:.3f} (their mean; "
             "(prior): held by the prior at that size; (held): no data reach it, at the sized segments' median)"]
    for k in range(0, len(cells), 3):
        lines.append("    " + "   ".join(cells[k:k + 3]).rstrip())
    return lines


def _noise_lines(cal) -> list[str]:
    """The noise line (learnt or given: median and range) and the left/right symmetry line."""
    out = []
    unused = set(cal.unused_markers)  # a marker no trial shows has only its segment's noise: not in the range
    shown = {n: sd for n, sd in cal.noise.items() if n not in unused}
    if shown:
        v = 1000 * np.array(list(shown.values()))
        lo, hi = int(v.argmin()), int(v.argmax())
        names = list(shown)
        how = "learnt" if cal.noise_learnt else "given"
        out.append(f"  {'noise SD (mm)':22s}{how:>12s}  median {np.median(v):.2f}, "
                   f"{v.min():.2f} ({names[lo]}) to {v.max():.2f} ({names[hi]})")
    sym = symmetry_table(cal)
    if sym["scale_difference"]:
        st = cal.settings.priors
        mirrored = mirror_clause(sym)
        out.append(f"  {'left/right':22s}{'':12s}  segment lengths differ by up to "
                   + (asymmetry_clause(sym["segment_length"]) or "-")
                   + (f", mirrored centres by up to {mirrored}" if mirrored else "")
                   + (f" (symmetry prior SD {100 * st.symmetry_scale:g} %, {1000 * st.symmetry_centre:g} mm)"
                      if st.symmetry_scale or st.symmetry_centre else " (no symmetry prior)"))
    return out


def left_out_lines(left: list[tuple[str, str]]) -> list[str]:
    """The summary's lines for the trial markers left out, (label, reason) each; the clause naming the segments
    that carry no markers (association.shared_clause), when every reason ends with it, said once after them."""
    reasons, shared = shared_clause([reason for _, reason in left]) if len(left) > 1 else ([r for _, r in left], None)
    lines = [f"  left out {label}: {reason}" for (label, _), reason in zip(left, reasons, strict=True)]
    return lines + ([f"  left out, all {len(left)}: {shared}"] if shared else [])


UNUSED_SHOWN = 12  # model markers the trials never show, named in the summary (all of them in the report)


def on_axis_labels(cal: Calibration) -> list[str]:
    """The lateral markers Priors.on_axis kept on their held hinge axes (the knee's, ankle's or elbow's axis not
    calibrated, the marker seen): as the problem chose them (calibrate.problem.priors.on_axis_markers)."""
    st, m = cal.settings, cal.model
    if st.priors.on_axis <= 0 or not {"axis", "centre", "marker"} <= set(st.free):
        return []
    held_segments = set(st.hold_segments)
    child = {d: j.child for j in m.joints for d in j.dofs}

    def held(d: int) -> bool:
        name = m.dofs[d].name
        return name in st.hold_axes or child[name] in held_segments

    unseen = set(cal.unused_markers)
    return [m.markers[mi].name for _, mi in on_axis_markers(m, held) if m.markers[mi].name not in unseen]


#: An axis this many pair_axis SDs from its marker pair's line is named in the summary (the motion carried it there).
PAIR_FAR = 3.0


def axis_pair_table(cal: Calibration) -> list[dict]:
    """Each hinge whose axis was drawn along the line of two markers straddling it (Calibration.axis_pairs): the
    calibrated axis's angle from that line (deg) and the centre's distance from the markers' midpoint along the
    axis (mm, at the segment's scale), in the subject's geometry."""
    m, p = cal.model, cal.params
    out = []
    for dof, m1, m2 in cal.axis_pairs:
        d = m.dof_index(dof)
        ji = m.joint_index(m.dofs[d].joint)
        jt = m.joints[ji]
        a = hinge_axis(m, p, d)
        x1, x2 = p.marker[m.marker_index(m1)], p.marker[m.marker_index(m2)]
        e = (x2 - x1) / np.linalg.norm(x2 - x1)
        s = float(p.scale[m.segment_index(jt.parent)])
        out.append({"coordinate": dof, "markers": [m1, m2],
                    "angle_deg": math.degrees(math.acos(min(1.0, abs(float(a @ e))))),
                    "centre_from_midpoint_mm": 1000 * s * float(a @ (p.centre[ji] - 0.5 * (x1 + x2)))})
    return out


def pair_centre_table(cal: Calibration) -> list[dict]:
    """Each held hinge whose centre was drawn to the midpoint of the two markers straddling it
    (Calibration.pair_centres): the centre's distance from that midpoint (mm, at the segment's scale), in the
    subject's geometry."""
    m, p = cal.model, cal.params
    out = []
    for joint, m1, m2 in cal.pair_centres:
        ji = m.joint_index(joint)
        x1, x2 = p.marker[m.marker_index(m1)], p.marker[m.marker_index(m2)]
        s = float(p.scale[m.segment_index(m.joints[ji].parent)])
        out.append({"joint": joint, "markers": [m1, m2],
                    "centre_from_midpoint_mm": 1000 * s * float(np.linalg.norm(p.centre[ji] - 0.5 * (x1 + x2)))})
    return out


def landmark_table(cal: Calibration) -> list[dict]:
    """Each turning knee or ankle whose centre was held on the axis line through its landmarks (Calibration.landmarks:
    the epicondyles, the malleoli): its landmark markers, the centre's offset across the axis from their midpoint
    against the base model's (mm, at the parent segment's scale: what the prior's rows read) and the base model's
    offset itself, in the subject's geometry."""
    m, p = cal.model, cal.params
    out = []
    for joint, markers, target in cal.landmarks:
        ji = m.joint_index(joint)
        a = hinge_axis(m, p, m.dof_index(m.joints[ji].dofs[0]))
        x = np.mean([p.marker[m.marker_index(k)] for k in markers], axis=0)
        t = np.asarray(target)
        y = p.centre[ji] - x - t
        s = float(p.scale[m.segment_index(m.joints[ji].parent)])
        out.append({"joint": joint, "markers": list(markers),
                    "from_line_mm": 1000 * s * float(np.linalg.norm(y - a * float(a @ y))),
                    "base_offset_mm": 1000 * s * float(np.linalg.norm(t))})
    return out


#: A lateral marker held by the population's width (Calibration.population_widths) that ends more than this many
#: Priors.population_width SDs from the population's distance is flagged: the centres' priors hold its hinge centre
#: along the axis against the marker, as where the label names another point.  A simulated subject's medial epicondyle
#: labelled as the lateral one ends 3.1 SDs off, its medial malleolus 3.0 (tests/test_lateral_sides.py), the true labels
#: within 0.8; the public files' knees and ankles all within it since the slide leaves out the child's markers
#: (docs/benchmarks.md).
POPULATION_FAR = 2.5


def population_width_table(cal: Calibration) -> list[dict]:
    """Each hinge placed along its axis by the population's width (Calibration.population_widths): its lateral
    marker's distance from the centre along the axis, calibrated and the prior's (the base model's at the segment's
    scale), mm."""
    m, base = cal.model, _base_on_subject(cal)
    lateral = dict(lateral_markers_of(m))
    out = []
    for joint in cal.population_widths:
        marker = lateral[joint]
        seg = m.segment_index(m.joints[m.joint_index(joint)].parent)
        s = float(cal.params.scale[seg]) / float(base.scale[seg])
        calibrated = 1000 * lateral_distance(m, cal.params, base, joint, marker)
        prior = 1000 * s * lateral_distance(m, base, base, joint, marker)
        sds = abs(calibrated - prior) / (1000 * cal.settings.priors.population_width)
        out.append({"joint": joint, "marker": marker, "calibrated_mm": calibrated, "prior_mm": prior,
                    "prior_sds": sds, "far": sds > POPULATION_FAR})
    return out


def _population_line(cal: Calibration) -> list[str]:
    """The summary's line on the hinges placed along their axes by the population's width."""
    rows = population_width_table(cal)
    if not rows:
        return []
    text = ", ".join(f"{r['joint']} {r['calibrated_mm']:.0f}/{r['prior_mm']:.0f}" for r in rows)
    return [f"  widths       none measured: {', '.join(r['marker'] for r in rows)} held about the base model's "
            f"distance from their centres along the axes at the segment's scale (prior SD "
            f"{1000 * cal.settings.priors.population_width:g} mm; calibrated / prior, mm: {text}); a trial's measured "
            "widths take their place"]


def _population_far_lines(cal: Calibration) -> list[str]:
    """The summary's `implausible` lines of lateral markers held by the population's width that end beyond
    POPULATION_FAR SDs of it, but for a joint whose marker ended medial of its centre (_lateral_side_lines says it)."""
    medial = {j for j, v in lateral_sides(cal).items() if v["medial"]}
    return [f"{IMPLAUSIBLE}{r['joint']}: {r['marker']} ends {r['calibrated_mm']:.0f} mm from the centre along the "
            f"axis where the population's width puts it {r['prior_mm']:.0f} ({r['prior_sds']:.1f} SDs; no width "
            "measured): "
            "the centres' priors hold the centre there, as when the label names the "
            "medial epicondyle or malleolus, or another point (check it; --markers map.toml maps it)"
            for r in population_width_table(cal) if r["far"] and r["joint"] not in medial]


def _pair_line(cal: Calibration) -> list[str]:
    """The summary's line on the axes drawn along marker pairs, those the motion carried far from theirs named."""
    rows = axis_pair_table(cal)
    if not rows:
        return []
    sd = math.degrees(cal.settings.priors.pair_axis)
    far = [r for r in rows if r["angle_deg"] > PAIR_FAR * sd]
    text = "; ".join(f"{r['coordinate']} {r['angle_deg']:.1f} deg from {r['markers'][0]}-{r['markers'][1]}"
                     for r in rows)
    line = (f"  axis pairs   {text} (each axis drawn along the line of the two markers straddling its centre, prior "
            f"SD {sd:g} deg; its centre slid to their midpoint along it)")
    if far:
        line += (f"; {', '.join(r['coordinate'] for r in far)} beyond {PAIR_FAR:g} SDs: the trials' motion turned "
                 "the axis from the markers' line (skin moving over the segment, or a marker off its landmark); "
                 "--hold-axes keeps the base model's")
        # Markers of those hinges' segments that a static shows elsewhere than the moving trials, kept in the fit: the
        # segment's frame then differs between the static, which places the pair, and the moving trials, which turn
        # the axis (Rajagopal's left thigh cluster 26-51 mm: its knee 18.5 deg from its epicondyles, 11.9 without).
        m = cal.model
        parents = {m.joints[m.joint_index(m.dofs[m.dof_index(r["coordinate"])].joint)].parent for r in far}
        kept = sorted({mv.marker for mv in cal.moved_kept if mv.segment in parents})
        if kept:
            line += (f"; {', '.join(kept)} sit elsewhere on those segments in the still trials than in the moving "
                     "ones (the moved? line): --moved-markers leaves their still positions out")
    return [line]


def _pair_centre_line(cal: Calibration) -> list[str]:
    """The summary's line on the held axes' centres drawn to their marker pairs' midpoints (pair_centre_table)."""
    rows = pair_centre_table(cal)
    if not rows:
        return []
    text = "; ".join(f"{r['joint']} {r['centre_from_midpoint_mm']:.1f} mm from {'-'.join(r['markers'])}'s midpoint"
                     for r in rows)
    return [f"  pair centres {text} (each held axis's centre drawn to the midpoint of the two markers straddling it, "
            f"prior SD {1000 * cal.settings.priors.on_axis:.0f} mm: no motion places it)"]


def _held_list(cal, joints) -> str:
    """'lumbar (the base model's offset from pelvis's 5 markers, at the subject's scale); ...' for held centres."""
    return "; ".join(f"{j} ({_held_against(cal, j)}, at the subject's scale)" for j in joints)


def _held_against(cal, joint: str) -> str:
    """What a held centre (Settings.hold_centres) keeps: its offset from its parent segment's markers, where three
    or more of them are seen (Problem.held_centres; the change shown is then the frame's against the base model's),
    else its place in that segment's frame."""
    model = cal.model
    parent = model.joints[model.joint_index(joint)].parent
    seen = [mk.name for mk in model.markers if mk.segment == parent and mk.name not in set(cal.unused_markers)]
    if len(seen) >= 3:
        return f"the base model's offset from {parent}'s {len(seen)} markers"
    return f"the base model's place in {parent}'s frame ({len(seen)} markers seen there)"


def _placeholders(cal) -> list[str]:
    """The names of the base model's placeholder markers (calibrate.problem.priors.placeholder_markers) the trials
    show: markers the data alone place."""
    unused = set(cal.unused_markers)
    # The new markers (the trials' labels the base model lacks) start at one place too; each has its own 'new marker'
    # line, and the base model puts none of them anywhere.
    new = {m.label for m in cal.new_markers}
    model = cal.model
    return [model.markers[k].name for k in placeholder_markers(model, model.parameters())
            if model.markers[k].name not in unused and model.markers[k].name not in new]


def _moved_hint(cal, change) -> str:
    """For an unreliable joint centre, axis or marker: the kept moved markers (Calibration.moved_kept) on the
    segments it belongs to, which pull it (gait2392's back centre and its static's acromia), or ''."""
    model = cal.model
    if change.group in ("centre", "axis"):
        name = change.item if change.group == "centre" else model.dofs[model.dof_index(change.item)].joint
        j = model.joints[model.joint_index(name)]
        segments = {j.parent, j.child}
    elif change.group == "marker":
        segments = {model.markers[model.marker_index(change.item)].segment}
    else:
        segments = {change.item}
    near = [m for m in cal.moved_kept if m.segment in segments]
    if not near:
        return ""
    return ("; the still trial shows " + ", ".join(f"{m.marker} {1e3 * m.distance:.0f} mm" for m in near)
            + f" elsewhere on {', '.join(sorted({m.segment for m in near}))} than the moving trials (moved?): "
            "--moved-markers leaves those positions out")


def _by_still_trial(cal, records) -> list[tuple[str, list]]:
    """(the still trial's name, its records) for records that carry a `trial` index (moved markers, far
    joints), each trial once, in the records' order."""
    by_trial: dict[int, list] = {}
    for r in records:
        by_trial.setdefault(r.trial, []).append(r)
    return [(cal.trials[t].source or f"trial {t + 1}", rs) for t, rs in by_trial.items()]


def summary_text(cal) -> str:
    """Human-readable summary in the spirit of Ceres' Solver::Summary::FullReport()."""
    model, s = cal.model, cal.summary
    F = sum(t.n_frames for t in cal.trials)
    used = len(model.markers) - len(cal.unused_markers)
    n_new = sum(1 for m in cal.new_markers if m.segment is not None)
    n_said = sum(1 for m in cal.new_markers if m.segment is not None and m.declared)
    past = [m.past for m in cal.new_markers if m.segment is not None and m.past]
    how = [f"{n_said} on the segments the marker map's [segments] names"] if n_said else []
    if past:
        how.append(f"{len(past)} on {', '.join(dict.fromkeys(past))} past a joint no model marker poses")
    if n_new > n_said + len(past):
        how.append(f"{n_new - n_said - len(past)} by rigidity or the model's poses")
    n_free = len([c for c in cal.changes])  # count of reported quantities
    lines = ["calibrate: subject calibration"]
    for i, trial in enumerate(cal.trials):
        res = cal.residuals[cal.trial_frames(i)]
        weighed = (f" (still: its frames count as {cal.trial_weights[i]:g} in all, --still-weight)"
                   if cal.trial_weights and cal.trial_weights[i] < trial.n_frames else "")
        span = f" ({trial.times[0]:.4g} to {trial.times[-1]:.4g} s)" if trial.n_frames else ""
        lines.append(f"  {'trial' if i == 0 else '':13s}{trial.source or '(in memory)'}: {trial.n_frames} frames at "
                     f"{trial.rate:g} Hz{span}, marker RMS {1000 * marker_rms(res):.2f} mm{weighed}")
    if cal.still_only is not None:
        lines.append(f"  still only   {'every trial is' if len(cal.trials) > 1 else 'the trial is'} still (markers on "
                     f"different segments keep their distances to {1e3 * cal.still_only:.1f} mm SD; a walk's move "
                     "20-55 mm): no joint turns, so no motion places the joint centres and axes; they stay near the "
                     "base model's, scaled, where the priors of the centres and of the markers around them balance"
                     + (" (the ball joints' centres held, below)" if cal.still_centres else "")
                     + "; add a movement trial (calibrate STATIC WALK MODEL) to place the joints")
    lines += [
        f"  markers      {used}/{len(model.markers)} model markers seen"
        + ((f" ({n_new} new, placed on segments by rigidity or the model's poses)" if not n_said and not past
            else f" ({n_new} new: {', '.join(how)})") if n_new else "")
        + f", {left_out_clause(cal.ignored_labels)}, {len(cal.outliers)} outliers rejected",
        f"  model        {model.path.name}: {len(model.segments)} segments, {len(model.joints)} joints, "
        f"{model.nz} coordinates per frame",
        f"  unknowns     {F * model.nz} frame coordinates + geometric parameters "
        f"({', '.join(cal.settings.free)}); {n_free} quantities reported",
        "  mass         " + (f"{cal.mass:g} kg" + ("" if cal.mass_from in (None, "given") else f" ({cal.mass_from})")
                              + f": the base model's segment masses x{mass_factor(model, cal.mass):.3f}"
                              if cal.mass is not None else
                              f"{model.total_mass:g} kg, the base model's (give the subject's with --mass)"),
        *_measurement_lines(cal),
        *_lateral_side_lines(cal),
        *_population_far_lines(cal),
        *(["  locked       " + ", ".join(f"{k} at {math.degrees(v):g} deg" for k, v in cal.settings.lock)]
          if cal.settings.lock else []),
        *["  auto-locked  " + lk.text() for lk in cal.auto_locked],
        *(["  frames       segment frames turned to where their markers put them (--segment-frames)"]
          if cal.settings.segment_frames == "markers" and cal.neutral is None else []),
        *([f"  neutral      segment frames turned so that in "
           f"{cal.trials[cal.neutral].source or f'trial {cal.neutral + 1}'} "
           + (", ".join(f"{n} is {math.degrees(v):.3g} deg" for n, v in cal.pose) or "nothing") + " on average (the "
           "lab's static pose)" + (f"; not met: {', '.join(cal.pose_unset)} (held at another value, a frame its "
                                   "markers fix, or a turn the joint's range would undo; in brackets where the angle "
                                   "ends)" if cal.pose_unset else "")
           + (f"; not turned: {', '.join(f'{j} ({math.degrees(a):.0f} deg from it)' for j, a in cal.not_neutral)}: "
              "there the trials' angles would leave the joint's range" if cal.not_neutral else "")]
          if cal.neutral is not None and cal.pose is not None else []),
        *([f"  neutral      segment frames turned so that the joint angles of "
           f"{cal.trials[cal.neutral].source or f'trial {cal.neutral + 1}'} are zero on average"
           + (f"; not turned: {', '.join(f'{j} ({math.degrees(a):.0f} deg)' for j, a in cal.not_neutral)}: zero "
              f"there, the trials' angles would leave the joint's range (not the model's neutral pose; their zero "
              f"stays the model's)" if cal.not_neutral else "")]
          if cal.neutral is not None and cal.pose is None else []),
        *(["  axes held    " + ", ".join(cal.settings.hold_axes) + " (base model's" + "".join(_held_why(cal)) + ")"]
          if cal.settings.hold_axes else []),
        *([f"  on axis      {', '.join(on_axis)} drawn onto their held hinge axes (prior SD "
           f"{1000 * cal.settings.priors.on_axis:.0f} mm: the epicondyle or malleolus the axis passes through; no "
           "motion places the axis)"]
          if (on_axis := on_axis_labels(cal)) else []),
        *_pair_line(cal),
        *_pair_centre_line(cal),
        *_population_line(cal),
        *(["  centres held " + _held_list(cal, given) + " (--hold-centres)"]
          if (given := [j for j in cal.settings.hold_centres if j not in cal.still_centres
                             and j not in dict(cal.narrow_centres) and j not in cal.cluster_centres]) else []),
        *(["  centres held " + _held_list(cal, cal.cluster_centres) + ": the segment below carries only a cluster "
           "of new labels (a head band), whose places and the centre would trade"] if cal.cluster_centres else []),
        *(["  centres held " + _held_list(cal, narrow_c) + ": the moving trials turn "
           + ", ".join(f"{j} through {math.degrees(t):.0f} deg" for j, t in narrow_c.items())
           + f" at most about every axis but one (under {math.degrees(NARROW_TURN):.0f} deg: too little to place a "
           "centre of rotation against the skin's turn of the segments, and a turn about one axis leaves it anywhere "
           "along it), and the fit had carried "
           + ("it" if len(narrow_c) == 1 else "each") + " beyond its prior (--no-auto-hold leaves it there)"]
          if (narrow_c := dict(cal.narrow_centres)) else []),
        *([f"  centres held {', '.join(cal.still_centres)}: the trials are still and do not turn these ball joints, "
           "so no motion places their centres; each keeps the base model's offset from its parent segment's "
           "markers, at the subject's scale (--no-auto-hold leaves them to their priors"
           + ("; --hip-regression places the hips by Harrington's regression from the pelvis markers instead"
              if any(j.lower().startswith("hip") for j in cal.still_centres) else "") + ")"]
          if cal.still_centres else []),
        "",
        f"  {'':22s}{'start':>12s}{'final':>12s}",
        f"  {'marker RMS (mm)':22s}{1000 * marker_rms(cal.initial_residuals):12.3f}{1000 * cal.marker_rms:12.3f}"
        "  (start: the seeded geometry)",
        # The solve on every frame starts from the subsample's geometry, under the noise learnt until then: its
        # start is not the marker RMS's, and a noise learnt again before its last run can end it above its start.
        f"  {'cost, every frame':22s}{s.initial_cost:12.4e}{s.final_cost:12.4e}"
        + ("  (start: the subsample's geometry, under the noise learnt by then)" if s.coarse is not None else ""),
        *_noise_lines(cal),
        "",
        *([f"  coarse solve {s.coarse_frames} evenly spaced frames: {s.coarse.iterations} iterations, cost "
            f"{s.coarse.initial_cost:.4e} -> {s.coarse.final_cost:.4e} ({s.coarse.termination})"]
          if s.coarse is not None else []),
        *(["  then         " + ", ".join(f"{f} frames: {i} iterations" for f, i in s.levels)
           + " (larger evenly spaced subsamples of this long trial)"] if s.levels else []),
        *([f"  rounds       {(s.coarse or s).rounds} solves of the {'subsample' if s.coarse else 'trial'}: solved "
           "again after holding what it does not place (axes, centres, hinges locked) or leaving out moved markers "
           "(the figures above: the last)"]
          if (s.coarse or s).rounds > 1 else []),
        f"  iterations   {s.iterations} ({s.accepted} accepted){' on all frames' if s.coarse is not None else ''}",
        f"  termination  {'CONVERGED' if s.converged else 'NOT CONVERGED'}: {s.termination}",
        "  time (s)     " + "  ".join(f"{k} {v:.2f}" for k, v in cal.times.items())
        + f"  total {sum(cal.times.values()):.2f}",
        "",
        "  joint centres: change from base model, and from it at the subject's scale (mm; what the scale factors do "
        "not explain) +- posterior std (mm, worst axis; the markers' scatter only: skin artefact's bias adds to it)",
    ]
    for c in (c for c in cal.changes if c.group == "centre"):
        if not np.isfinite(c.std).any():
            # Not estimated (no marker seen on or below its segment, or its group not free): no posterior SD.
            lines.append(f"    {c.item:16s}{c.change:8.1f}{c.beyond_scale:8.1f}{'':9s}  ({_not_estimated(c)})")
        else:
            std = np.nanmax(c.std)
            flag = "" if c.identified else ("  (along the axis: prior)" if _slide_only(c) else
                                            "  (not identified; unreliable)" if c.unreliable else "  (held by prior)")
            if c.unreliable and (c.identified or _slide_only(c)):
                flag += "  (placed by the trial, yet far from the scaled base model's: unreliable)"
            if c.item in cal.settings.hold_centres:
                why = ("still trials" if c.item in cal.still_centres else "narrow turn" if c.item in
                       dict(cal.narrow_centres) else "a cluster of new labels below" if c.item in cal.cluster_centres
                       else "--hold-centres")
                flag = f"  (held: {why}; {_held_against(cal, c.item)})"
            lines.append(f"    {c.item:16s}{c.change:8.1f}{c.beyond_scale:8.1f} +- {std:5.2f}{flag}")
    axes = [c for c in cal.changes if c.group == "axis"]
    if axes:
        lines.append("  hinge axes: tilt from base model (deg) +- posterior std (deg; the markers' scatter only)")
        for c in axes:
            if not np.isfinite(c.std).any():
                lines.append(f"    {c.item:16s}{c.change:8.2f}{'':9s}  ({_not_estimated(c)})")
                continue
            std = np.nanmax(c.std)
            flag = "" if c.identified else "  (not identified; unreliable)" if c.unreliable else "  (held by prior)"
            if c.unreliable and c.identified:
                flag = "  (turned by the trial, yet far from the base model's: unreliable)"
            lines.append(f"    {c.item:16s}{c.change:8.2f} +- {std:5.2f}{flag}")
    lines += _scale_lines(cal)
    for c in cal.changes:
        if c.group == "centre" and c.unreliable and (c.identified or _slide_only(c)):
            lines.append(f"{IMPLAUSIBLE}centre[{c.item}]: {c.note}{_moved_hint(cal, c)}; --hold-centres "
                         f"{c.item} holds it at the base model's")
        if c.group == "axis" and c.unreliable and c.identified:
            lines.append(f"{IMPLAUSIBLE}axis[{c.item}]: {c.note}{_moved_hint(cal, c)}")
    # A held centre (Settings.hold_centres: given, or a still trial's ball joint) is named on its own line above.
    held = set(cal.settings.hold_centres)
    un = [c for c in cal.changes if not c.identified and not _slide_only(c)
          and not (c.group == "centre" and c.item in held)]
    if any(_slide_only(c) for c in cal.changes):
        lines.append("  every hinge centre's place along its axis is held by its prior (no motion defines it)")
    if un and cal.still_only is not None and not any(c.unreliable for c in un):
        # Statics alone identify nothing a motion would (the still-only line says why): counted, not listed.
        kinds = {"scale": ("scale", "scales"), "centre": ("centre", "centres"), "axis": ("axis", "axes"),
                 "marker": ("marker position", "marker positions")}
        counts = {g: sum(c.group == g for c in un) for g in kinds}
        lines.append("  not identified by this trial (still: held by their priors): " + ", ".join(
            f"{n} {kinds[g][n > 1]}" for g, n in counts.items() if n) + " (the report's unidentified names them)")
    elif un:
        far = sum(c.unreliable for c in un)
        lines.append("  not identified by this trial (held by their priors" + (f"; {far} carried further than "
                     "their priors allow, unreliable" if far else "") + f"): {len(un)}")
        un = sorted(un, key=lambda c: not c.unreliable)  # the unreliable first
        for c in un[:12]:
            hint = _moved_hint(cal, c) if c.unreliable else ""
            if c.unreliable and c.group == "centre":
                hint += f"; --hold-centres {c.item} holds it at the base model's"
            lines.append(f"    {c.name}: {c.note}{hint}")
        if len(un) > 12:
            lines.append(f"    ... and {len(un) - 12} more (see the report)")
    first, moot, last = seed_note_groups(cal.seed.notes, cal.seed.taken)  # the report keeps each note
    if moot:
        first.append(f"{len(moot)} notes on the MTB seed, moot: the start did not take it (the report's seed notes)")
    # A joint into a segment the markers cannot place has no seed, and the unresolved line says why: one line for them
    unplaced = {u.segment for u in cal.unresolved}
    into = {j.name for j in cal.model.joints if j.child in unplaced or j.parent in unplaced}
    blind = [n for n in first + last if n.split(":", 1)[0] in into and "no joint-centre seed (no marker" in n]
    for note in first + last:
        if len(blind) < 2 or note not in blind:
            lines.append(f"  seed: {note}")
        elif note == blind[0]:
            lines.append(f"  seed: no joint-centre seed for {', '.join(n.split(':', 1)[0] for n in blind)} (into "
                         "or out of segments the markers cannot place: unresolved below); base model used")
    notes = cal.coordinate_notes
    if cal.still_only is not None:
        # A still trial shows no coordinate turning (the still-only line): one line for them all.
        still = [n for n in notes if isinstance(n, StillNote)]
        notes = tuple(n for n in notes if not isinstance(n, StillNote))
        if still:
            held = "the hinges' axes are held at the base model's and " if any(n.axis_held for n in still) else ""
            lines.append(f"  note: {len(still)} coordinates turn no more than one frame's markers fix them, as in "
                         f"any still trial: {held}every angle's zero rests on the priors (each coordinate's note in "
                         "the report)")
    for note in notes[:4]:
        lines.append(f"  note: {note.text()}")
    if len(notes) > 4:
        more = ", ".join(n.coordinate for n in notes[4:])
        lines.append(f"  ... and {len(notes) - 4} more notes ({more}; see the report)")
    for i, mapping in enumerate(cal.label_maps):
        renamed = [m for m in mapping if m.how in ("map", "alias", "description")]
        if renamed:
            where = f" in {cal.trials[i].source}" if len(cal.trials) > 1 else ""
            lines.append(f"  labels{where}: {len(renamed)} renamed to the model's ("
                         + ", ".join(f"{m.trial_label} -> {m.label} ({m.how})" for m in renamed[:6])
                         + (", ..." if len(renamed) > 6 else "") + ")")
    lines.extend(f"  new marker {m.label} on {m.segment}: {m.reason}" for m in cal.new_markers if m.segment is not None)
    lines.extend(left_out_lines([(m.label, m.reason) for m in cal.new_markers if m.segment is None]))
    if poor := poor_fit_line(cal):
        lines.append(IMPLAUSIBLE + poor)
    lines.extend(IMPLAUSIBLE + line for line in leg_proportion_lines(cal))
    bad = cal.implausible
    if bad:
        median = float(np.median(cal.params.scale))
        causes = "; ".join(b.cause() for b in bad if b.centres)
        lines.append(IMPLAUSIBLE + ", ".join(b.text() for b in bad)
                     + f" against the subject's median {median:.2f}: the markers do not fit the model there"
                     + (f" ({causes})" if causes else "") + "; "
                     f"check the labels of {', '.join(dict.fromkeys(x for b in bad for x in b.labels)) or '-'} "
                     "(a swap for the whole trial?)")
    turned = cal.static_asymmetry
    if turned:
        lines.append(IMPLAUSIBLE + "; ".join(f"{cal.trials[h.trial].source or f'trial {h.trial + 1}'} (static): "
                                                   f"{h.text()}" for h in turned)
                     + ": unless the subject stood asymmetrically there, one side's segment frames sit turned where "
                     "its markers leave them to the priors, and that joint's angles carry the difference as an offset"
                     + _foot_hint(cal, [h.joint for h in turned]) + _one_side_hint(cal, turned))
    replaced_only = "" if cal.settings.moved_markers else (
        f" (a marker of their segment {1e3 * REPLACED_MIN:.0f} mm or more away: re-placed, not skin; without "
        "--moved-markers only such are left out)")
    for tag, records, done in (("moved   ", cal.moved, "their positions there left out, the model keeps the moving "
                                "trials' place" + replaced_only),
                               ("moved?  ", cal.moved_kept, "kept in the fit, which then bends the geometry between "
                                "the two places; --moved-markers leaves their positions there out")):
        for name, ms in _by_still_trial(cal, records):
            lines.append(f"  {tag}     {name} (still) shows "
                         + ", ".join(f"{m.marker} {1e3 * m.distance:.0f} mm" for m in ms)
                         + " elsewhere on their segments than the moving trials (slipped, re-placed, or skin moved "
                         f"with the pose): {done}")
    for name, fs in _by_still_trial(cal, cal.far_joints):
        lines.append(f"  far pose     {name} (still) holds "
                     + ", ".join(f"{f.joint} {math.degrees(f.angle):.0f} deg" for f in fs)
                     + " from every pose the moving trials reach (arms out in a static, at the sides in a walk: "
                     "a model's shoulder without its blade cannot be both); its markers beyond them left out "
                     "of the fit there, its angles beyond them fitted to them afterwards (--keep-far-joints "
                     "keeps them)")
    if cal.joint_markers:
        lines.append("  joint marker " + ", ".join(f"{m.marker} at {m.joint}" for m in cal.joint_markers)
                     + ": points computed at joint centres (by the lab, or --hip-regression), each kept at its "
                     f"offset from the centre within {1e3 * cal.settings.priors.joint_marker:g} mm (they place the "
                     "centres)")
    if held := _placeholders(cal):
        lines.append(f"  placeholders {', '.join(held)}: the base model puts each at one place with other markers of "
                     "its segment (a cluster left for OpenSim's marker placer): placed by the trials alone (prior SD "
                     f"{1e3 * cal.settings.priors.placeholder:g} mm), they neither size nor turn their segments")
    tied = {m.joint for m in cal.joint_markers}
    loose = [h for h in cal.hip_motion if not h.places_centre and h.joint not in tied]
    if said := [h for h in loose if h.joint not in cal.still_centres]:  # (held: the centres-held line says)
        lines.append("  hips         the trials turn " + " and ".join(h.text() for h in said)
                     + f": a hip centre is placed by motion through {math.degrees(FUNCTIONAL_RANGE):.0f} deg in two "
                     "of its angles (a star arc); a walk's do not, and on real walks the centres end 28-65 mm from "
                     "the labs' (docs/benchmarks.md): --hip-regression places them by Harrington's regression from "
                     "the pelvis markers")
    if conv := [h for h in loose if h.as_model and h.from_regression > REGRESSION_FAR]:
        lines.append("  hips         " + " and ".join(f"{h.joint} {1e3 * h.from_regression:.0f} mm" for h in conv)
                     + " from Harrington's regression on the pelvis markers, but "
                     + " and ".join(f"{1e3 * h.from_model:.0f}" for h in conv)
                     + f" mm from where {cal.base_model.path.name if cal.base_model is not None else 'the base model'} "
                     f"puts its own hips on them ({1e3 * conv[0].model_offset:.0f} mm from Harrington's on its own "
                     "markers): its convention, not flagged")
    if far := [h for h in loose if h.implausible]:
        width, asis = far[0].width
        lines.append(IMPLAUSIBLE + " and ".join(f"{h.joint} {1e3 * h.from_regression:.0f} mm" for h in far)
                     + " from Harrington's regression on the pelvis markers (its error on CT 12 +- 6 mm), the hips "
                     f"{1e3 * width:.0f} mm apart where the ASIS markers are {1e3 * asis:.0f} (Harrington's: "
                     f"{1e3 * harrington_width(asis):.0f}): "
                     + ("nothing turns in a still trial, so the base model's offset from the pelvis markers placed "
                        "them (--hip-regression, or a movement trial, places them better)"
                        if set(cal.still_centres) >= {h.joint for h in far} else
                        "nothing turns in a still trial, so only the priors of the centres and the pelvis and thigh "
                        "markers placed them" if cal.still_only is not None else
                        "the trials' motion does not place them (hips above), the thigh markers' skin did")
                     + ("; the regression, tried, fits the markers worse (hips below)" if "times worse" in
                        cal.hip_regression_auto else "; --hip-regression places them by the regression"))
    if wide := [h for h in cal.hip_motion if h.places_centre and h.nowhere and h.joint not in tied]:
        width, asis = wide[0].width
        lines.append(f"{IMPLAUSIBLE}the hips {1e3 * width:.0f} mm apart where the ASIS markers are {1e3 * asis:.0f} "
                     f"(Harrington's: {1e3 * harrington_width(asis):.0f}): "
                     f"{'outside the pelvis' if wide[0].outside else 'on the pelvis midline'}, though the trials turn "
                     + " and ".join(h.text() for h in wide) + ", enough to place a centre: the thighs' skin, or a "
                     "thigh turned about its length by markers that do not fix that turn, moved them ("
                     + " and ".join(f"{h.joint} {1e3 * h.from_regression:.0f} mm" for h in wide)
                     + " from Harrington's regression); --hip-regression places them by the regression")
    if cal.hip_regression_auto:
        lines.append(f"  hips         Harrington's regression (hip_regression {cal.settings.hip_regression}) "
                     f"{cal.hip_regression_auto}")
    for i, x in cal.jittery:
        lines.append(f"  jitters      {cal.trials[i].source or f'trial {i + 1}'}: {x.text()}")
    for i, x in cal.exchanged_back:
        lines.append(f"  exchanged    {cal.trials[i].source or f'trial {i + 1}'}: {x.text()}")
    for x in cal.relabelled:
        ref = (_trial_name(cal, x.reference),) if x.reference >= 0 else ()
        lines.append(f"  relabelled   {x.text(_trial_name(cal, x.trial), *ref)}; check the labelling")
    for i, j, misfit, pairs in cal.trials_apart:
        lines.append(f"  subjects?    {cal.trials[i].source or f'trial {i + 1}'} and "
                     f"{cal.trials[j].source or f'trial {j + 1}'}: their markers on each segment keep distances "
                     f"{100 * misfit:.0f} % apart (the median over {pairs} pairs; one subject's trials read 0.5-7 %): "
                     "trials of two subjects?  Calibrate each subject's trials on their own")
    for x in cal.places_apart:
        lines.append(f"  places apart {x.text(*(_trial_name(cal, k) for k in x.trials))}")
    if cal.places_apart:
        from .moved import PLACES_APART_ADVICE, girdle_advice

        acromia = sorted({a for x in cal.places_apart for a in x.acromia})
        lines.append(f"               ({PLACES_APART_ADVICE}" + (f"; {girdle_advice(acromia)}" if acromia else "")
                     + ")")
    for m in cal.new_markers:
        if m.check:
            lines.append(f"  check label  {m.label}: the marker map's [segments] puts it on {m.segment}, yet {m.check}")
    for i, m in cal.misplaced:
        lines.append(f"  check label  {cal.trials[i].source or f'trial {i + 1}'}: {m.text()} (exchanged for the whole "
                     "trial? each label of an exchanged pair can look misplaced; nothing was changed)")
    for x in cal.exchanged:
        lines.append(f"  check labels {x.text([_trial_name(cal, k) for k in range(len(cal.trials))])} "
                     + (f"(their positions in {_trial_name(cal, x.odd)} left out of the fit: exchange them in its file "
                        "and calibrate again to use them)" if x.odd is not None else
                        "(the labels kept, the lab's protocol taken: the fit starts with each where the base model "
                        "has the other, and its priors hold them there)" if x.protocol else
                        "(nothing was changed: exchange them in the trial's file that has them wrong)"))
    unresolved = cal.unresolved
    if unresolved:
        lines.append(f"  unresolved   {len(unresolved)} segments the markers cannot place (their coordinates "
                     f"locked): {', '.join(u.segment for u in unresolved)}")
        for u in unresolved[:8]:
            lines.append(f"    {u.segment}: {', '.join(u.coordinates) or '-'}: {u.reason}")
        if len(unresolved) > 8:
            lines.append(f"    ... and {len(unresolved) - 8} more (see the report)")
    for i, fs in enumerate(cal.unplaced_frames):
        if fs:
            lines.append(f"  unplaced     {_trial_name(cal, i)}: frames {runs_text(fs)} ({len(fs)} of "
                         f"{cal.trials[i].n_frames}, from 0) show too few markers to place {cal.model.root}: their "
                         "poses are bridged from the frames either side that place it (held at the trial's edges), "
                         "not fitted")
    for i, us in cal.unplaced_in_trial:
        coords = list(dict.fromkeys(c for u in us for c in u.coordinates))
        segs = ", ".join(u.segment for u in us)
        what = ", ".join(coords[:6]) + (f" and {len(coords) - 6} more" if len(coords) > 6 else "")
        if i in cal.unplaced_held:
            dofs = [c for c in coords if c != "root"]
            lines.append(f"  unplaced     {_trial_name(cal, i)}: its markers do not place {segs}, which the other "
                         f"trials place: in its motion {', '.join(dofs[:6])}"
                         + (f" and {len(dofs) - 6} more" if len(dofs) > 6 else "") + " are held at 0"
                         + (f" and its {cal.model.root} rides with the segments its markers place"
                            if "root" in coords else "") + " (as `calibrate ik` holds them)")
        else:
            lines.append(f"  unplaced     {_trial_name(cal, i)}: its markers do not place {segs}, which the other "
                         f"trials place: its frames' {what} rest on the priors and the neighbouring frames there, "
                         "not on its markers (read them with care)")
    outputs = set().union(*(t.model_outputs for t in cal.trials))
    if outputs:
        named = ", ".join(sorted(outputs)[:3]) + (", ..." if len(outputs) > 3 else "")
        lines.append(f"  {len(outputs)} Vicon model outputs ignored ({named}: not markers; a marker map line "
                     "naming one, or a model marker of its name, reads it as that marker)")
    misaligned: dict[str, list] = {}
    for k in cal.knee_axes:
        if k.misaligned:
            misaligned.setdefault(k.source, []).append(k)
    for source, ks in misaligned.items():
        lines.append(f"  plug-in gait {source}: " + "; ".join(k.text() for k in ks)
                     + ": its femur frame is turned about the thigh (a thigh wand or KAD off the plane the knee flexes "
                     "in, the usual cause), which mixes its knee flexion into varus-valgus")
    unlabelled = [lab for lab in cal.ignored_labels if UNLABELLED.fullmatch(lab)]
    if unlabelled:
        lines.append(f"  {len(unlabelled)} unlabelled trajectories ignored ({', '.join(unlabelled[:4])}"
                     f"{', ...' if len(unlabelled) > 4 else ''}): label them to use them")
    named = [lab for lab in cal.ignored_labels if not UNLABELLED.fullmatch(lab)]
    if named and not any(m.segment is None for m in cal.new_markers):
        lines.append(f"  ignored trial labels (not in the model): {', '.join(named)}")
    if cal.outliers:
        per: dict[str, int] = {}
        for o in cal.outliers:
            per[o.marker] = per.get(o.marker, 0) + 1
        lines.append(f"  outliers rejected ({cal.settings.outliers:g} noise SDs): "
                     + ", ".join(f"{k} x{v}" for k, v in sorted(per.items(), key=lambda kv: -kv[1])[:10]))
    if cal.unused_markers:
        unused = cal.unused_markers
        more = len(unused) - UNUSED_SHOWN
        shown = ", ".join(unused[:UNUSED_SHOWN]) + (
            f", ... and {more} more: the report's marker_set.unused_model_markers" if more > 0 else "")
        lines.append(f"  model markers never seen: {len(unused)} ({shown}; base positions kept)")
    return "\n".join(lines)


def _slide_only(c) -> bool:
    """A hinge centre identified across its axis (only its slide along the axis is prior-held)."""
    return c.status is Identified.ACROSS_AXIS


def _not_estimated(c) -> str:
    """Why a quantity has no posterior SD, for the summary's tables: held where no marker reaches it (its note
    up to its first colon, e.g. 'no marker seen on or below ulna_l'), or not free."""
    return "held: " + c.note.split(":")[0] if c.status is Identified.UNSEEN else "held: not free"


def _per_trial(cal: Calibration, paths, what: str) -> list:
    """One output path per trial from None, a path (a single trial) or a sequence of paths."""
    out = [] if paths is None else [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    if out and len(out) != len(cal.trials):
        raise CalibrateError(f"{len(out)} {what} outputs for {len(cal.trials)} trials; give one per trial")
    return out


def write_outputs(cal: Calibration, urdf=None, motion=None, report=None, overwrite: bool = False,
                  extra_times: dict[str, float] | None = None, osim=None, mot=None, html=None,
                  progress: Callable[[float], None] | None = None, c3d=None, mjcf=None,
                  qpos=None, errors=None, marker_set=None, error_markers=None, scale_set=None,
                  marker_locations=None) -> dict[str, Path]:
    """Write the subject URDF, the motion CSV(s), the report JSON, the HTML report of it
    (calibrate.calibration.html), each trial as a C3D with calibrate's joint centres, model markers and joint
    angles beside its markers (calibrate.calibration.c3d_result), for OpenSim the subject as an .osim model
    and the motions as .mot files, and for MuJoCo the subject as an MJCF model and the motions as qpos CSVs
    (calibrate.io.mjcf), each trial's marker errors as OpenSim's IK tool reports them (`errors`: its
    _ik_marker_errors.sto; calibrate.io.osim_export.ik_marker_errors) and the subject's markers as an OpenSim
    MarkerSet file (`marker_set`, as the Scale tool's MarkerPlacer writes its output_marker_file) and its segments'
    scale factors as an OpenSim ScaleSet file (`scale_set`, as its ModelScaler writes its output_scale_file;
    calibrate.io.osim_export.scale_set_text) (whichever are given), and where an IK setup asks OpenSim for them
    (report_marker_locations), each trial's model marker locations (`marker_locations`: its
    _ik_model_marker_locations.sto, or None for a trial without; calibrate.io.osim_export.ik_model_marker_locations).
    `error_markers`: per trial the markers its errors and marker locations count (an IK setup's tracked markers, as
    OpenSim's IK counts them: calibrate.io.osim_setup.SetupOutputs.tracked_of), or None for every marker the fit
    uses.

    `motion`, `mot`, `c3d`, `qpos`, `errors`: one path per trial (a single path for a single trial).  Every
    destination is checked first (its folder exists; it is not the base model; it does not exist unless
    `overwrite`), then all are written at once or none (calibrate.io.outputs.write_all).  The report's times are
    `cal.times` with the time of this writing (so far) and `extra_times`.  `progress(share done)`, by the
    motion CSVs' frames (most of a long trial's writing).
    """
    motions = _per_trial(cal, motion, "motion")
    mots = _per_trial(cal, mot, ".mot")
    stos = _per_trial(cal, errors, "marker errors")
    locs = _per_trial(cal, marker_locations, "marker locations")
    c3ds = _per_trial(cal, c3d, "C3D")
    qposes = _per_trial(cal, qpos, "qpos")
    targets = {k: Path(v) for k, v in (("urdf", urdf), ("report", report), ("html", html)) if v is not None}
    if html is not None and Path(html).suffix.lower() not in (".html", ".htm"):
        raise CalibrateError(f"{html}: the HTML report needs an .html name")
    keys = ["motion"] if len(motions) == 1 else [f"motion[{i}]" for i in range(len(motions))]
    targets.update({k: Path(v) for k, v in zip(keys, motions, strict=True)})
    opensim = {k: Path(v) for k, v in [("osim", osim), ("marker_set", marker_set), ("scale_set", scale_set),
                                        *((f"mot[{i}]", m) for i, m in enumerate(mots)),
                                        *((f"errors[{i}]", e) for i, e in enumerate(stos)),
                                        *((f"locations[{i}]", x) for i, x in enumerate(locs))]
               if v is not None}
    mujoco = {k: Path(v) for k, v in [("mjcf", mjcf), *((f"qpos[{i}]", q) for i, q in enumerate(qposes))]
              if v is not None}
    c3d_targets = [Path(v) for v in c3ds]
    if c3d_targets:
        from ..io.c3d import C3D_MAX_FRAMES

        long = [t for t in cal.trials if t.n_frames > C3D_MAX_FRAMES]
        if long:
            raise CalibrateError(f"{long[0].source or 'a trial'}: {long[0].n_frames} frames are more than a C3D file "
                                 f"holds ({C3D_MAX_FRAMES}); leave out the C3D output (--c3d)")
    check_targets([*targets.values(), *opensim.values(), *mujoco.values(), *c3d_targets], overwrite,
                  inputs={(cal.base_model or cal.model).path: "that is the base model; refusing to overwrite it "
                                                              "(choose another -o)"},
                  same="the URDF, motion and report outputs must all be different files")
    t0 = time.perf_counter()

    made: list[dict] = []  # the report, made once for the JSON and the HTML

    def the_report() -> dict:
        if not made:
            timed = replace(cal, times={**cal.times, "write": time.perf_counter() - t0, **(extra_times or {})})
            rep = calibration_report(timed)
            rep["outputs"] = {k: str(v) for k, v in targets.items() if not k.startswith("motion")}
            rep["outputs"]["motion"] = [str(targets[k]) for k in keys] if motions else []
            if c3d_targets:
                rep["outputs"]["c3d"] = [str(t) for t in c3d_targets]
            for name, files in (("osim", opensim), ("marker_set", opensim), ("scale_set", opensim),
                                ("mjcf", mujoco)):  # the subject's
                if name in files:
                    rep["outputs"][name] = str(files[name])
            for name, files in (("mot", opensim), ("errors", opensim), ("locations", opensim),
                                ("qpos", mujoco)):  # one per trial (where written)
                if any(k.startswith(f"{name}[") for k in files):
                    rep["outputs"][name] = [str(v) for k, v in files.items() if k.startswith(f"{name}[")]
            made.append(rep)
        return made[0]

    def write_report(path: Path) -> None:
        put_text(path, json.dumps(the_report(), indent=1, allow_nan=False, default=_json_default) + "\n")

    def write_html(path: Path) -> None:
        put_text(path, report_html(the_report()))

    writers = {}
    # The subject's URDF document, made once: the URDF output and the OpenSim exports are of it.
    text = urdf_text(cal.model, cal.params, cal.mass) if "urdf" in targets or opensim or mujoco else ""
    if text:  # what the file is, ahead of the base model's own header comments
        text = with_comment(text, provenance(cal, targets.get("report")))
    if "urdf" in targets:
        writers[targets["urdf"]] = lambda path: put_text(path, text)
    before = np.cumsum([0, *(m.times.size for m in cal.motions[:len(keys)])])  # frames written before each motion
    for i, (k, m) in enumerate(zip(keys, cal.motions, strict=False)):  # keys is empty without motion outputs
        share = None if progress is None else \
            (lambda done, i=i, m=m: progress((before[i] + done * m.times.size) / max(before[-1], 1)))
        writers[targets[k]] = lambda path, m=m, share=share: put_text(path, motion_csv_text(m, share))
    if "report" in targets:
        writers[targets["report"]] = write_report
    if "html" in targets:
        writers[targets["html"]] = write_html
    # The subject as the written URDF loads (named after it), for OpenSim's names and masses and MuJoCo's bodies.
    subject = Model(Path(urdf) if urdf is not None else cal.model.path, text=text) if opensim or mujoco else None
    if opensim:
        from ..io.osim_export import (
            ik_marker_errors,
            ik_model_marker_locations,
            marker_errors_text,
            marker_locations_text,
            marker_set_text,
            mot_text,
            osim_text,
            scale_set_text,
        )

        osim_made: list[str] = []  # the subject's .osim document, made once for the model and its marker set

        def subject_osim() -> str:
            if not osim_made:
                osim_made.append(osim_text(subject))
            return osim_made[0]

        if "osim" in opensim:
            writers[opensim["osim"]] = lambda path: put_text(path, subject_osim())
        if "marker_set" in opensim:
            writers[opensim["marker_set"]] = lambda path: put_text(path, marker_set_text(subject_osim()))
        if "scale_set" in opensim:  # each body at its segment's scale factor (the subject's own geometry is at 1)
            scales = {sg.name: float(s) for sg, s in zip(cal.model.segments, cal.params.scale, strict=True)}
            writers[opensim["scale_set"]] = lambda path: put_text(path, scale_set_text(subject_osim(), scales))
        for i, m in enumerate(cal.motions[:len(mots)]):
            target = opensim[f"mot[{i}]"]
            writers[target] = lambda path, m=m, name=target.stem: put_text(path, mot_text(subject, m, name))
        used = [n for n in cal.model.marker_names if n not in cal.unused_markers]
        counted = list(error_markers) if error_markers is not None else [None] * max(len(stos), len(locs))
        if len(counted) != max(len(stos), len(locs)):
            raise CalibrateError(f"{len(counted)} marker lists for {len(cal.trials)} trials' marker errors or "
                                 "locations; give one per trial (None: every marker the fit uses)")
        for i, (t, m, own) in enumerate(zip(cal.trials, cal.motions, counted, strict=False)):
            keep = None if own is None else set(own)
            mk = used if keep is None else [n for n in used if n in keep]  # the markers each trial's files count
            if f"errors[{i}]" in opensim:
                writers[opensim[f"errors[{i}]"]] = lambda path, t=t, m=m, mk=mk: put_text(
                    path, marker_errors_text(m.times, ik_marker_errors(cal.model, cal.params, t, m, mk)))
            if f"locations[{i}]" in opensim:
                writers[opensim[f"locations[{i}]"]] = lambda path, t=t, m=m, mk=mk: put_text(
                    path, marker_locations_text(m.times, *ik_model_marker_locations(cal.model, cal.params, t, m, mk)))
    if mujoco:
        from ..io.mjcf import mjcf_text, qpos_csv_text  # MuJoCo export: only for these outputs

        if "mjcf" in mujoco:
            writers[mujoco["mjcf"]] = lambda path: put_text(path, mjcf_text(subject))
        for i, m in enumerate(cal.motions[:len(qposes)]):
            writers[mujoco[f"qpos[{i}]"]] = lambda path, m=m: put_text(path, qpos_csv_text(subject, m))
    if c3d_targets:
        from ..io.c3d import write_c3d
        from .c3d_result import calibrated_trials

        for target, trial in zip(c3d_targets, calibrated_trials(cal), strict=False):
            writers[target] = lambda path, trial=trial: write_c3d(path, trial)
    write_all(writers)
    return {**targets, **opensim, **mujoco, **{f"c3d[{i}]": t for i, t in enumerate(c3d_targets)}}


def provenance(cal: Calibration, report: Path | None = None, names: Sequence[str] | None = None) -> str:
    """A subject model file's first words on what it is: whose trials, calibrated by which calibrate from which base
    model, and the report that says how ("The subject of static.c3d and walk.c3d, calibrated by calibrate 0.1.0 from
    human.urdf; its report: static_report.json.  The comments after this one are the base model's.").  `names`: the
    trials' names where their files do not say them (a tracked trial: the C3D written of it)."""
    if names is None:
        names = [Path(t.source).name if t.source else f"trial {i + 1}" for i, t in enumerate(cal.trials)]
    trials = names[0] if len(names) == 1 else ", ".join(names[:-1]) + f" and {names[-1]}"
    base = (cal.base_model or cal.model).path.name
    how = f"; its report: {Path(report).name}" if report is not None else ""
    return (f"The subject of {trials}, calibrated by calibrate {__version__} from {base}{how}.  The comments after "
            "this one are the base model's.")


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
