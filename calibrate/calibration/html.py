"""The HTML report of a calibration: one self-contained file (plotly.js embedded once, no network)
made from the report JSON alone (calibrate.calibration.report), so `calibrate report REPORT.json`
rebuilds it without the trials.

Order, for a reader at a glance: the notes (unresolved segments, still joints, held axes, parameters
the trial does not identify), the summary tables, marker errors (RMS per marker, marker x time heat
map with rejected positions marked, residual curves per trial), joint angles against the base model's
limits, parameter changes with their posterior SD and identifiability, segment lengths base vs
subject (left and right side by side).  Figures: plotly (interactive: hover for values, zoom a long
trial), see docs/report.md.
"""

from __future__ import annotations

import html
import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from ..errors import CalibrateError
from ..io.labels import UNLABELLED
from ..io.outputs import check_targets, put_text, write_all
from ..seed.association import shared_clause
from .regression import HIP_OUTSIDE

STYLE = """
body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.8em}
table{border-collapse:collapse;margin:.5em 0;font-size:.9em}td,th{border:1px solid #ddd;padding:2px 8px}
th{background:#f3f3f3;text-align:left}td.n{text-align:right;font-variant-numeric:tabular-nums}
.notes{background:#fff6e0;border-left:4px solid #e0a000;padding:.5em 1em}.ok{color:#2a7a2a}.bad{color:#b00020}
.muted{color:#777}
"""


_UUID = re.compile(r"\b[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}\b")


def _e(x) -> str:
    return html.escape(str(x))


def _libraries(software: dict[str, str]) -> str:
    """' (Python 3.11.7; casadi 3.8.2, ...)' from a report's "software" (calibrate.software), '' from an older
    report without it."""
    libs = [f"{k} {v}" for k, v in software.items() if k not in ("calibrate", "python")]
    return f" (Python {software.get('python', '?')}; {', '.join(libs)})" if software else ""


def _num(v, fmt: str = "{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def _table(head: list[str], rows: list[list], numeric: set[int] | None = None) -> str:
    numeric = numeric or set()
    out = ["<table><tr>" + "".join(f"<th>{_e(h)}</th>" for h in head) + "</tr>"]
    for row in rows:
        out.append("<tr>" + "".join(f"<td class=n>{_e(c)}</td>" if i in numeric else f"<td>{_e(c)}</td>"
                                    for i, c in enumerate(row)) + "</tr>")
    return "".join(out) + "</table>"


def _title(text: str) -> dict:
    return {"text": text}


def _figure(fig: dict, template: dict, height: int = 420, top: int = 40) -> str:
    """One figure's <div> and script.  `fig` is plotly's figure as plain data ({"data": [traces], "layout": {...}},
    plotly.js's own schema), written without plotly's per-value validation: the report's figures carry every
    frame's residual and angle, and validating them took most of the page's time (docs/benchmarks.md)."""
    from plotly.io import to_html

    layout = {"template": template, **fig.get("layout", {}), "height": height,
              "margin": {"l": 60, "r": 20, "t": top, "b": 50}}
    return to_html({"data": fig["data"], "layout": layout}, validate=False, full_html=False, include_plotlyjs=False,
                   config={"displaylogo": False})


def _notes(report: dict) -> str:
    items = []
    conv = report["solver"]["converged"]
    items.append(f"<li class={'ok' if conv else 'bad'}>solver {'converged' if conv else 'DID NOT CONVERGE'}: "
                 f"{_e(report['solver']['termination'])}</li>")
    for b in report.get("implausible", []):
        partner = (f", {_e(b['partner'])} {b.get('partner_scale', 0):.2f} on the other side" if b.get("partner")
                   else "")
        cause = f"{_e(b['note'])}; " if b.get("no_markers") else ""
        items.append(f"<li class=bad>implausible size: {_e(b.get('segment'))} scale {b.get('scale', 0):.2f} "
                     f"({b.get('relative_to_median', 0):.2f} of the subject's median{partner}); {cause}check the "
                     f"labels {_e(', '.join(b.get('check_labels', [])) or '-')}</li>")
    static_pose = report.get("static_pose") or {}
    for h in static_pose.get("flagged", []):
        items.append(f"<li class=bad>implausible static pose in {_e(h.get('trial'))}: {_e(h.get('left'))} "
                     f"{h.get('left_deg', 0):.1f}° against {_e(h.get('right'))} {h.get('right_deg', 0):.1f}° "
                     f"({h.get('difference_deg', 0):.1f}° apart): unless the subject stood asymmetrically, one side's "
                     "segment frames sit turned where its markers leave them to the priors</li>")
    if static_pose.get("flagged") and static_pose.get("advice"):  # once, after the pairs it is about
        items.append(f"<li class=bad>implausible static poses: {_e(static_pose['advice'])}</li>")
    for f in report.get("implausible_flags", []):  # a centre or axis a trade carried far (the rest: below)
        if f.startswith(("centre[", "axis[")) or ": hip to knee " in f:  # ... or a knee carried along the leg
            items.append(f"<li class=bad>implausible {_e(f)}</li>")
    measured_flags = set()
    for j, v in ((report.get("measurements") or {}).get("lateral_mm") or {}).items():
        if v.get("flagged"):
            measured_flags.add(j)
            items.append(f"<li class=bad>implausible {_e(j)} centre: {_e(v.get('marker'))} "
                         f"{v.get('calibrated_mm', 0):.0f} mm from it along the axis, the measured width puts it "
                         f"{v.get('measured_mm', 0):.0f} mm lateral"
                         + ("" if v.get("used") else " (the width was not used)") + "</li>")
    for j, v in (report.get("lateral_sides") or {}).items():
        if v.get("medial") and j not in measured_flags:
            items.append(f"<li class=bad>implausible {_e(j)} centre: its lateral marker {_e(v.get('marker'))} ends "
                         f"{-v.get('lateral_mm', 0):.0f} mm medial of it along the axis (the centre and the marker "
                         "traded along the axis, or the label names another point)</li>")
    for x in report.get("exchanged_labels", []):
        items.append(f"<li class=bad>check labels: {_e(x.get('note'))}"
                     + (f"; their positions in {_e(x['odd_trial'])} left out of the fit" if x.get("odd_trial") else "")
                     + ("; the labels kept, the base model's places of the two exchanged for the fit (the lab's "
                        "protocol)" if x.get("protocol") else "")
                     + "</li>")
    for x in report.get("trials_apart", []):
        a, b = (x.get("trials") or ["?", "?"])[:2]
        items.append(f"<li class=bad>subjects? {_e(a)} and {_e(b)}: their markers on each segment keep distances "
                     f"{100 * x.get('segment_distances_apart', 0):.0f} % apart (over {x.get('pairs', 0)} pairs; one "
                     "subject's trials read 0.5-7 %): trials of two subjects?</li>")
    from .moved import PLACES_APART_ADVICE, girdle_advice

    for x in report.get("places_apart", []):
        a, b = (x.get("trials") or ["?", "?"])[:2]
        far = ", ".join(f"{_e(m.get('marker'))} {m.get('apart_mm', 0):.0f}" for m in x.get("markers") or [])
        girdle = girdle_advice(x["acromia"]) if x.get("acromia") else ""
        items.append(f"<li class=bad>places apart: {_e(a)} and {_e(b)} put {far} mm apart on their segments: "
                     f"{_e(PLACES_APART_ADVICE)}" + (f"; {_e(girdle)}" if girdle else "") + "</li>")
    for x in report.get("exchanged_back", []):
        a, b = (x.get("labels") or ["?", "?"])[:2]
        f0, f1 = (x.get("frames") or [0, 0])[:2]
        items.append(f"<li class=bad>exchanged: {_e(a)} and {_e(b)} ({_e(x.get('trial'))}) exchanged in frames "
                     f"{f0}-{f1} and not back (their distances to their segments' markers "
                     + ("keep steady to " if x.get("judged_by") == "rigidity" else "fit the base model's ")
                     + f"{x.get('misfit_exchanged_mm', 0):.0f} mm RMS exchanged, "
                     f"{x.get('misfit_as_labelled_mm', 0):.0f} as labelled): exchanged back there; check the "
                     "labelling</li>")
    for x in report.get("relabelled", []):
        read = zip(x.get("labels", []), x.get("read_as", []), strict=False)
        pairs = ", ".join(f"{_e(a)} as {_e(b)}" for a, b in read)
        than = _e(x["reference"]) if x.get("reference") else "the moving trials"
        items.append(f"<li class=bad>relabelled: {_e(x.get('trial'))}{'' if x.get('reference') else ' (still)'} "
                     f"names the markers of {_e(x.get('segment'))} otherwise than {than}: read {pairs} (a symmetric "
                     "cluster labelled the other way round); check the labelling</li>")
    for x in report.get("jittery_markers", []):
        items.append(f"<li class=bad>jitters: {_e(x.get('label'))} ({_e(x.get('trial'))}) scatters "
                     f"{x.get('noise_sd_mm', 0):.0f} mm SD from frame to frame (white noise; the trial's markers "
                     f"{x.get('trial_median_mm', 0):.2g} mm): its positions in {x.get('frames_left_out', 0)} of the "
                     f"{x.get('frames_seen', 0)} frames it is seen left out; check its reconstruction</li>")
    for m in report.get("marker_set", {}).get("new", []):
        if m.get("check"):
            items.append(f"<li class=bad>check label {_e(m.get('label'))}: the marker map's [segments] puts it on "
                         f"{_e(m.get('segment'))}, yet {_e(m.get('check'))}</li>")
    for m in report.get("suspect_labels", []):
        items.append(f"<li class=bad>check label {_e(m.get('label'))} ({_e(m.get('trial'))}): it moves with "
                     f"{_e(m.get('moves_with'))}'s markers (distances steady to "
                     f"{m.get('distance_sd_other_mm', 0):.1f} mm SD), not with {_e(m.get('segment'))}'s "
                     f"({_e(', '.join(m.get('segment_labels', [])))}: {m.get('distance_sd_own_mm', 0):.1f} mm); "
                     "exchanged for the whole trial?"
                     + ("".join(f" {_e(a)} and {_e(b)}?" for a, b in m.get("exchanges", []))) + "</li>")
    for m in report.get("moved_markers", []):
        items.append(f"<li>moved marker {_e(m.get('marker'))}: {_e(m.get('trial'))} (still) shows it "
                     f"{m.get('distance_mm', 0):.0f} mm elsewhere on {_e(m.get('segment'))} than the moving trials "
                     f"({m.get('sigmas', 0):.0f} SD of their spread); its positions there left out</li>")
    if report.get("still_only_mm") is not None:
        items.append(f"<li class=bad>still only: no trial moves (markers on different segments keep their distances "
                     f"to {report['still_only_mm']:.1f} mm SD): no motion places the joint centres and axes, which "
                     "stay near the base model's, scaled"
                     + (f" (the centres of {_e(', '.join(report['still_centres']))} held at the base model's offset "
                        "from their segments' markers)" if report.get("still_centres") else "")
                     + "; add a movement trial to place them</li>")
    for m in report.get("moved_markers_kept", []):
        items.append(f"<li>moved marker? {_e(m.get('marker'))}: {_e(m.get('trial'))} (still) shows it "
                     f"{m.get('distance_mm', 0):.0f} mm elsewhere on {_e(m.get('segment'))} than the moving trials "
                     f"({m.get('sigmas', 0):.0f} SD of their spread); kept in the fit (--moved-markers leaves its "
                     f"positions there out)</li>")
    for f in report.get("far_joints", []):
        items.append(f"<li>far pose: {_e(f.get('trial'))} (still) holds {_e(f.get('joint'))} "
                     f"{f.get('angle_deg', 0):.0f}&deg; from every pose the moving trials reach; its "
                     f"{_e(', '.join(f.get('markers', [])))} beyond it left out there</li>")
    for m in report.get("joint_centre_markers", []):
        items.append(f"<li>joint-centre marker {_e(m.get('marker'))} at {_e(m.get('joint'))}: kept "
                     f"{m.get('offset_mm', 0):.1f} mm from the centre (base model "
                     f"{m.get('base_offset_mm', 0):.1f} mm); "
                     "its positions place the centre</li>")
    tied = {m.get("joint") for m in report.get("joint_centre_markers", [])}
    for h in report.get("hip_motion", []):
        if not h.get("places_centre", True) and h.get("joint") not in tied:
            items.append(f"<li{' class=bad' if h.get('implausible') else ''}>{_e(h.get('joint'))}: the trials turn it "
                         "through "
                         + ", ".join(f"{_e(d)} {v:.0f}" for d, v in h.get("range_deg", {}).items())
                         + " deg, too little in two of its angles to place its centre (a walk's motion does not)"
                         + (f"; it ended {h['from_regression_mm']:.0f} mm from Harrington's regression on the pelvis "
                            "markers (its error 12 &plusmn; 6 mm): implausible" if h.get("implausible") else "")
                         + (f"; {h['from_regression_mm']:.0f} mm from Harrington's regression, but "
                            f"{h['from_model_mm']:.0f} mm from where the base model puts its own hips on these markers "
                            f"({h['model_offset_mm']:.0f} mm from Harrington's on its own): its convention"
                            if h.get("as_model") and h.get("from_regression_mm", 0) > 40 else "")
                         + "; <code>--hip-regression</code> places it by Harrington's regression</li>")
        elif h.get("implausible") and h.get("joint") not in tied:  # placed by the motion, yet where no hip is
            outside = h["hip_width_mm"] > HIP_OUTSIDE * h["asis_width_mm"]
            where = "outside the pelvis" if outside else "on the pelvis midline"
            items.append(f"<li class=bad>{_e(h.get('joint'))}: the hips {h['hip_width_mm']:.0f} mm apart where the "
                         f"ASIS markers are {h['asis_width_mm']:.0f}: {where}, though the trials turn it "
                         "through " + ", ".join(f"{_e(d)} {v:.0f}" for d, v in h.get("range_deg", {}).items())
                         + f" deg; {h['from_regression_mm']:.0f} mm from Harrington's regression: implausible; "
                         "<code>--hip-regression</code> places it by Harrington's regression</li>")
    if report.get("hip_regression_auto"):
        mode = (report.get("settings") or {}).get("hip_regression", "auto")
        items.append(f"<li>hips by Harrington's regression (hip_regression {_e(mode)}): "
                     f"{_e(report['hip_regression_auto'])}"
                     "</li>")
    for k in report.get("plugin_gait_knees", []):
        if k.get("misaligned"):
            items.append(f"<li>Plug-in Gait in {_e(k.get('trial'))}: its {_e(k.get('joint'))} axis is "
                         f"{k.get('plugin_gait_axis_deg', 0):.0f} deg from the axis its tibia turns about"
                         + (f" (calibrate's: {k['our_axis_deg']:.0f} deg)" if k.get("our_axis_deg") is not None else "")
                         + ": its femur frame is turned about the thigh (a thigh wand or KAD off the plane the "
                         "knee flexes in), which mixes its knee flexion into varus-valgus</li>")
    from .report import runs_text

    for t in report.get("unplaced_frames", []):
        k = t.get("trial", 0)
        name = (report.get("trials") or [{}] * (k + 1))[k].get("source") or f"trial {k + 1}"
        runs = runs_text(runs=t.get("runs", []))
        items.append(f"<li>{_e(name)}: frames {_e(runs)} ({len(t.get('frames', []))} frames) show too few markers to "
                     "place the root: their poses are bridged from the frames either side, not fitted</li>")
    for t in report.get("unplaced_in_trial", []):
        k = t.get("trial", 0)
        name = (report.get("trials") or [{}] * (k + 1))[k].get("source") or f"trial {k + 1}"
        segs = ", ".join(u.get("segment", "") for u in t.get("segments", []))
        items.append(f"<li>{_e(name)}: its markers do not place {_e(segs)}, which the other trials place: "
                     + ("in its motion their coordinates are held at 0, as <code>calibrate ik</code> holds them</li>"
                        if t.get("held") else "its frames' coordinates there rest on the priors and the neighbouring "
                        "frames, not on its markers</li>"))
    for u in report.get("unresolved", []):
        items.append(f"<li>unresolved segment {_e(u.get('segment'))} (its coordinates locked: "
                     f"{_e(', '.join(u.get('coordinates', [])) or '-')}): {_e(u.get('reason', ''))}</li>")
    narrow = report.get("narrow_axes_deg") or {}
    if quiet := [n for n in report.get("held_axes") or [] if n not in narrow]:
        items.append(f"<li>axes held at the base model's (the trials do not show these joints moving): "
                     f"{_e(', '.join(quiet))}</li>")
    if narrow:
        items.append("<li>axes held at the base model's (the moving trials turn these joints too little to place an "
                     "axis against the skin's turn of the segments): "
                     f"{_e(', '.join(f'{n} ({t:.0f} deg)' for n, t in narrow.items()))}</li>")
    for g in report.get("gimbal_axes") or []:
        items.append(f"<li>axes held at the model's: {_e(', '.join(g.get('coordinates', [])))} turn about one "
                     f"centre through {_e(', '.join(g.get('bodies', [])))} (light, no markers): one ball in the "
                     "source's angle convention, not axes to calibrate</li>")
    if report.get("on_axis_markers"):
        items.append(f"<li>lateral markers kept on their held hinge axes (the epicondyle or malleolus the axis "
                     f"passes through; no motion places the axis): {_e(', '.join(report['on_axis_markers']))}</li>")
    if pairs := report.get("axis_pairs"):
        items.append("<li>axes drawn along the line of the two markers straddling each joint (the lab's anatomical "
                     "axis; centres slid to their midpoint): "
                     + _e("; ".join(f"{r['coordinate']} {r['angle_deg']:.1f} deg from {'-'.join(r['markers'])}"
                                    for r in pairs)) + "</li>")
    if pairs := report.get("pair_centres"):
        items.append("<li>held axes' centres drawn to the midpoint of the two markers straddling each joint (no motion "
                     "places them): " + _e("; ".join(f"{r['joint']} {r['centre_from_midpoint_mm']:.1f} mm from "
                                                     f"{'-'.join(r['markers'])}'s midpoint" for r in pairs)) + "</li>")
    if held := report.get("landmarks"):
        items.append("<li>knee and ankle centres held on the axis line through their landmark markers (the "
                     "epicondyles, the malleoli; the motion alone does not place them): "
                     + _e("; ".join(f"{r['joint']} {r['from_line_mm']:.1f} mm from {'-'.join(r['markers'])}'s line"
                                    for r in held)) + "</li>")
    if widths := report.get("population_widths"):
        items.append("<li>no width measured: lateral markers held about the base model's distance from their centres "
                     "along the axes, at the segment's scale (calibrated / prior, mm): "
                     + _e(", ".join(f"{r['marker']} {r['calibrated_mm']:.0f}/{r['prior_mm']:.0f}" for r in widths))
                     + "</li>")
    narrow_c = report.get("narrow_centres_deg") or {}
    if given := [j for j in (report.get("settings") or {}).get("hold_centres", [])
                 if j not in report.get("still_centres", []) and j not in narrow_c
                 and j not in report.get("cluster_centres", [])]:
        items.append(f"<li>centres held at the base model's offset from their parent segment's markers "
                     f"(--hold-centres): {_e(', '.join(given))}</li>")
    if cluster := report.get("cluster_centres"):
        items.append("<li>centres held at the base model's offset from their parent segment's markers, the segment "
                     f"below carrying only a cluster of new labels: {_e(', '.join(cluster))}</li>")
    if narrow_c:
        items.append("<li>centres held at the base model's offset from their parent segment's markers, the moving "
                     "trials turning their joints too little to place a centre against the skin: "
                     f"{_e(', '.join(f'{n} ({t:.0f} deg)' for n, t in narrow_c.items()))}</li>")
    for lk in report.get("auto_locked", []):
        items.append(f"<li>locked: {_e(lk.get('note', ''))}</li>")
    if report.get("not_neutral"):
        held = ", ".join(f"{_e(n.get('joint'))} ({n.get('mean_deg', 0):.0f} deg)" for n in report["not_neutral"])
        items.append(f"<li>neutral trial: not turned to zero there, {held}: zero there, the trials' angles would "
                     "leave the joint's range (their zero stays the model's)</li>")
    if report.get("neutral_pose_deg") is not None:  # a lab's static pose (its Scale setup's coordinate tasks)
        pose = ", ".join(f"{_e(n)} {v:.3g} deg" for n, v in report["neutral_pose_deg"].items()) or "nothing"
        unset = report.get("neutral_pose_not_set") or []
        items.append(f"<li>static pose: segment frames turned so that the neutral trial holds {pose} on average"
                     + (f"; not met: {_e(', '.join(unset))}" if unset else "") + "</li>")
    for n in report.get("notes", []):
        items.append(f"<li>{_e(n)}</li>")
    seed = report.get("seed", {})
    first, moot, last = seed_note_groups(seed.get("notes", []), seed.get("taken", True))
    items.extend(f"<li>seed: {_e(n)}</li>" for n in first)
    if moot:
        items.append("<li>seed: what the MTB seed could not place (moot: the start did not take it):<ul>"
                     + "".join(f"<li>{_e(n)}</li>" for n in moot) + "</ul></li>")
    items.extend(f"<li>seed: {_e(n)}</li>" for n in last)
    far = report.get("unreliable", [])
    if far:
        items.append(f"<li>{len(far)} parameters carried further from the base model's than their priors allow, "
                     f"whether or not these trials identify them (unreliable: a trade the data do not separate, or "
                     f"skin artefact; --hold-axes keeps an axis, --hold-centres a centre at the base model's): "
                     f"{_e(', '.join(far))}</li>")
    # A held centre (settings.hold_centres: given, or a still trial's ball joint) is named where the holds are.
    held = {f"centre[{j}]" for j in (report.get("settings") or {}).get("hold_centres", [])}
    un = [name for name in report.get("unidentified", []) if name not in held]
    if un:
        items.append(f"<li>{len(un)} parameters not identified by these trials (held by their priors): "
                     f"{_e(', '.join(un))}</li>")
    for m in report.get("marker_set", {}).get("new", []):
        items.append(f"<li>new marker {_e(m.get('label'))} placed on {_e(m.get('segment'))}"
                     + (" (the marker map's [segments])" if m.get("declared") else "")
                     + (" (past a joint no model marker poses)" if m.get("past_joint") else "") + "</li>")
    left = report.get("marker_set", {}).get("left_out", [])
    if left:
        reasons, shared = shared_clause([m.get("reason", "") for m in left])
        items.append(f"<li>{len(left)} trial labels left out" + (f" ({_e(shared)})" if shared else "") + ":<ul>"
                     + "".join(f"<li>{_e(m.get('label'))}: {_e(reason)}</li>"
                               for m, reason in zip(left, reasons, strict=True)) + "</ul></li>")
    if report.get("marker_set", {}).get("unused_model_markers"):
        items.append("<li>model markers never seen (base positions kept): "
                     f"{_e(', '.join(report['marker_set']['unused_model_markers']))}</li>")
    if report["outliers"]["count"]:
        per = sorted(report["outliers"]["per_marker"].items(), key=lambda kv: -kv[1])
        items.append(f"<li>{report['outliers']['count']} marker positions rejected as outliers "
                     f"({report['outliers']['threshold_noise_sd']:g} noise SDs): "
                     + _e(", ".join(f"{k} x{v}" for k, v in per[:12])) + "</li>")
    return "<div class=notes><h2 id=notes>Notes</h2><ul>" + "".join(items) + "</ul></div>"


def left_out_clause(ignored: Sequence[str]) -> str:
    """'N trial labels left out', and the unlabelled trajectories among `ignored` counted apart (Vicon's '*115': a
    file's 42 ghosts had read as 50 labels left out beside its 8 real ones, pig_walk on Rajagopal2016)."""
    unlabelled = sum(1 for lab in ignored if UNLABELLED.fullmatch(lab))
    return (f"{len(ignored) - unlabelled} trial labels left out"
            + (f" and {unlabelled} unlabelled trajectories ignored" if unlabelled else ""))


def _summary(report: dict) -> str:
    m, s, mk = report["model"], report["solver"], report["markers"]
    trials = _table(["trial", "frames", "rate (Hz)", "marker RMS (mm)", "max (mm)", "outliers"],
                    [[t["source"] or "(in memory)", t["frames"] if "counted_as_frames" not in t else
                      f"{t['frames']} (counted as {t['counted_as_frames']:g})", f"{t['rate_hz']:g}", _num(t["rms_mm"]),
                      _num(t["max_mm"]), t["outliers"]] for t in report["trials"]], {1, 2, 3, 4, 5})
    mass = report.get("mass", {})
    rows = [
        ["model", f"{m['source']}: {m['segments']} segments, {m['joints']} joints, {m['dof']} coordinates per "
                  f"frame, {m['markers']} markers ({m['new_markers']} new)"],
        ["markers", f"{len(report['marker_set']['used'])} used, "
                    f"{left_out_clause(report['marker_set']['ignored_labels'])}, "
                    f"{report['outliers']['count']} outliers rejected"],
        ["marker RMS (mm)", f"start {_num(mk['initial_rms_mm'], '{:.3f}')}, final {_num(mk['rms_mm'], '{:.3f}')}, "
                            f"largest {_num(mk['max_mm'])}"],
        ["cost", f"{s['initial_cost']:.4e} -> {s['final_cost']:.4e}"],
        ["iterations", f"{s['iterations']} ({s['accepted_steps']} accepted)"
                       + (f"; coarse solve of {s['coarse']['frames']} frames: {s['coarse']['iterations']}"
                          if s.get("coarse") else "")],
        ["termination", f"{'CONVERGED' if s['converged'] else 'NOT CONVERGED'}: {s['termination']}"],
        ["mass", f"{mass.get('subject_kg')} kg (segment masses x{mass.get('factor', 1):.3f}"
                 + (f"; from {mass['from']})" if mass.get("from") not in (None, "given") else ")")
                 if mass.get("subject_kg") else f"{mass.get('base_kg')} kg, the base model's"],
        ["free parameters", ", ".join(report["settings"]["free"])],
        *([["subject's size", f"{report['subject_size']:.3f} x the base model's (the mean segment scale, the scale "
                              "priors' centre)"]] if report.get("subject_size") is not None else []),
        ["noise", "learnt per marker" if report["noise"]["learnt"] else f"{report['settings']['noise_mm']:g} mm"],
        ["time (s)", "  ".join(f"{k} {v:.2f}" for k, v in report["times_s"].items())
                     + f"  total {sum(report['times_s'].values()):.2f}"],
        ["calibrate", report.get("calibrate_version", "") + _libraries(report.get("software") or {})],
    ]
    outs = report.get("outputs", {})
    if outs:
        rows.append(["outputs", ", ".join(str(v) if not isinstance(v, list) else ", ".join(v) for v in outs.values())])
    meas = report.get("measurements") or {}
    if meas.get("lateral_mm"):
        rows.append(["measured widths", f"{meas.get('source')}: lateral marker to joint centre along the axis, "
                     "calibrated / measured (mm): " + ", ".join(
                         f"{j} {v['calibrated_mm']:.0f}/{v['measured_mm']:.0f}" + ("" if v["used"] else " (not used)")
                         for j, v in meas["lateral_mm"].items())])
    sym = report.get("symmetry", {})
    clause, mirrored = asymmetry_clause(sym.get("segment_length") or {}), mirror_clause(sym)
    if clause:
        rows.append(["left/right", f"segment lengths differ by up to {clause}"
                     + (f", mirrored centres by up to {mirrored}" if mirrored else "")])
    return "<h2 id=summary>Summary</h2>" + trials + _table(["", ""], rows)


def _marker_figures(report: dict, template: dict) -> str:
    per = report["markers"]["per_marker"]
    names = sorted(per, key=lambda n: -per[n]["rms_mm"])
    bars = {"data": [{"type": "bar", "x": names, "y": [per[n]["rms_mm"] for n in names], "name": "RMS",
                      "error_y": {"type": "data", "symmetric": False, "visible": True,
                                  "array": [per[n]["max_mm"] - per[n]["rms_mm"] for n in names]}}],
            "layout": {"title": _title("marker RMS per marker (mm; whisker up to the largest)"),
                       "yaxis": {"title": _title("mm")}}}
    out = ["<h2 id=markers>Marker errors</h2>", _figure(bars, template, 380)]
    series = report.get("series")
    if not series:
        return "".join(out) + "<p class=muted>(this report has no series: made by an older calibrate)</p>"
    rejected = report["outliers"]["rejected"]
    for i, (tr, ts) in enumerate(zip(report["trials"], series["trials"], strict=False)):
        name = tr["source"] or f"trial {i + 1}"
        markers = [n for n in names if n in ts["residual_mm"]]
        z = [ts["residual_mm"][n] for n in markers]
        block = ts["block"]
        heat = {"data": [{"type": "heatmap", "x": ts["times_s"], "y": markers, "z": z, "colorscale": "Viridis",
                          "colorbar": {"title": _title("mm")}, "hoverongaps": False,
                          "hovertemplate": "%{y} at %{x:.2f} s: %{z:.1f} mm<extra></extra>"}],
                "layout": {"title": _title(f"{name}: residual per marker over time (mm"
                                           + (f"; largest of each {block} frames" if block > 1 else "")
                                           + "; red x: rejected positions)"),
                           "xaxis": {"title": _title("time (s)")}, "yaxis": {"autorange": "reversed"}}}
        rej = [o for o in rejected if o["trial"] == i and o["marker"] in markers]
        if rej:
            t = [ts["times_s"][min(o["frame"] // block, len(ts["times_s"]) - 1)] for o in rej]
            heat["data"].append({"type": "scatter", "x": t, "y": [o["marker"] for o in rej], "mode": "markers",
                                 "name": "rejected", "marker": {"symbol": "x", "color": "red", "size": 9},
                                 "text": [f"rejected: {o['error_mm']:.1f} mm" for o in rej]})
        curves = {"data": [{"type": "scatter", "x": ts["times_s"], "y": ts["residual_mm"][n], "name": n,
                            "mode": "lines"} for n in markers],
                  "layout": {"title": _title(f"{name}: residual curves per marker (mm)"),
                             "xaxis": {"title": _title("time (s)")}, "yaxis": {"title": _title("mm")}}}
        out += [_figure(heat, template, max(300, 14 * len(markers) + 120)), _figure(curves, template, 380)]
    return "".join(out)


def _grid(rows: int, cols: int, titles: list[str], vertical_spacing: float) -> tuple[dict, list[tuple[str, str]]]:
    """A grid of rows x cols subplots as plotly's make_subplots lays it out (the same domains, its default
    horizontal spacing 0.2 / cols, a title over each cell), as plain layout data: (layout, each cell's (x, y)
    axis names, row by row)."""
    hs = 0.2 / cols
    width = (1.0 - hs * (cols - 1)) / cols
    height = (1.0 - vertical_spacing * (rows - 1)) / rows
    layout: dict = {"annotations": []}
    axes = []
    for k in range(rows * cols):
        r, c = divmod(k, cols)
        x0, y1 = c * (width + hs), 1.0 - r * (height + vertical_spacing)
        n = "" if k == 0 else str(k + 1)
        layout[f"xaxis{n}"] = {"domain": [x0, x0 + width], "anchor": f"y{n}"}
        layout[f"yaxis{n}"] = {"domain": [y1 - height, y1], "anchor": f"x{n}"}
        axes.append((f"x{n}", f"y{n}"))
        if k < len(titles):
            layout["annotations"].append({"text": titles[k], "x": x0 + 0.5 * width, "y": y1, "xref": "paper",
                                          "yref": "paper", "xanchor": "center", "yanchor": "bottom",
                                          "showarrow": False, "font": {"size": 16}})
    return layout, axes


def _angle_figures(report: dict, template: dict) -> str:
    series = report.get("series")
    if not series:
        return ""
    limits = series["limits_deg"]
    out = ["<h2 id=angles>Joint angles</h2><p class=muted>Shaded: the base model's range of each coordinate."
           "</p>"]
    for i, (tr, ts) in enumerate(zip(report["trials"], series["trials"], strict=False)):
        dofs = list(ts["angles_deg"])
        if not dofs:
            continue
        cols = 4
        rows = (len(dofs) + cols - 1) // cols
        layout, axes = _grid(rows, cols, dofs, min(0.08, 0.5 / rows))
        layout["title"] = _title(f"{tr['source'] or f'trial {i + 1}'}: joint angles (deg) over time (s)")
        data = []
        for k, d in enumerate(dofs):
            xa, ya = axes[k]
            y = ts["angles_deg"][d]
            lo, hi = limits.get(d, [None, None])
            if lo is not None and hi is not None:
                data.append({"type": "scatter", "x": ts["times_s"] + ts["times_s"][::-1],
                             "y": [hi] * len(y) + [lo] * len(y), "fill": "toself",
                             "fillcolor": "rgba(100,150,255,0.18)",
                             "line": {"width": 1, "color": "rgba(60,100,200,0.6)", "dash": "dot"},
                             "hoverinfo": "skip", "showlegend": False, "xaxis": xa, "yaxis": ya})
            span = [v for v in [*y, lo, hi] if v is not None]
            if span:  # the range's edges inside the plot
                pad = 0.08 * (max(span) - min(span) or 1.0)
                layout["yaxis" + ya[1:]]["range"] = [min(span) - pad, max(span) + pad]
            data.append({"type": "scatter", "x": ts["times_s"], "y": y, "mode": "lines", "name": d,
                         "showlegend": False, "line": {"color": "#1f4e99"}, "xaxis": xa, "yaxis": ya})
        out.append(_figure({"data": data, "layout": layout}, template, 190 * rows + 110, top=80))
    return "".join(out)


def _verdict(p: dict) -> str:
    """A parameter's identified column: yes, no (held by its prior), or unreliable (far beyond its prior, or a
    centre the trial places where no anatomy does)."""
    if p.get("unreliable"):
        return "yes (unreliable)" if p["identified"] else "no (unreliable)"
    return "yes" if p["identified"] else "no (prior)"


def _parameters(report: dict, template: dict) -> str:
    params = report["parameters"]
    rows = []
    for p in params:
        std = [v for v in p["std"] if v is not None]
        rows.append([p["name"], p["group"], p["unit"], " ".join(_num(v, "{:.4g}") for v in p["base"]),
                     " ".join(_num(v, "{:.4g}") for v in p["value"]), f"{p['change']:.4g}",
                     _num(max(std) if std else None, "{:.3g}"), _verdict(p), p.get("note", "")])
    out = ["<h2 id=parameters>Parameters: change from the base model</h2>"]
    for group, unit in (("centre", "mm"), ("axis", "deg"), ("scale", "fraction"), ("marker", "mm")):
        sel = [p for p in params if p["group"] == group]
        if not sel:
            continue
        sd = [max((v for v in p["std"] if v is not None), default=None) for p in sel]
        colour = {"yes": "#2a7a2a", "no (prior)": "#c08000", "no (unreliable)": "#b02020",
                  "yes (unreliable)": "#b02020"}
        verdicts = [_verdict(p) for p in sel]
        fig = {"data": [{"type": "bar", "x": [p["name"] for p in sel], "y": [p["change"] for p in sel],
                         "error_y": {"type": "data", "array": [v or 0 for v in sd], "visible": True},
                         "marker": {"color": [colour[v] for v in verdicts]},
                         "hovertext": [f"identified: {v}" for v in verdicts]}],
               "layout": {"title": _title(f"{group}: change ({unit}) +- posterior SD (worst axis); green: "
                                          "identified, amber: held by its prior, red: unreliable"),
                          "yaxis": {"title": _title(unit)}}}
        out.append(_figure(fig, template, 360))
    out.append(_table(["parameter", "group", "unit", "base", "subject", "change", "posterior SD", "identified",
                       "note"], rows, {5, 6}))
    return "".join(out)


def _segments(report: dict, template: dict) -> str:
    lengths = (report.get("series") or {}).get("segment_lengths") or {}
    if not lengths:
        return ""
    names = list(lengths)
    pairs, single = [], []
    for n in names:
        if n.endswith("_l") and n[:-2] + "_r" in lengths:
            pairs.append(n[:-2])
        elif not (n.endswith("_r") and n[:-2] + "_l" in lengths):
            single.append(n)
    x = [f"{lengths[n]['segment']} (to {n})" for n in single]
    base = [lengths[n]["base_mm"] for n in single]
    xs, left, right, lb = [], [], [], []
    for p in pairs:
        a, b = lengths[p + "_l"], lengths[p + "_r"]
        xs.append(f"{a['segment'][:-2]} (to {p})")
        left.append(a["subject_mm"])
        right.append(b["subject_mm"])
        lb.append(a["base_mm"])
    bars = ((xs + x, lb + base, "base model", "#999"), (xs, left, "subject left", "#1f77b4"),
            (xs, right, "subject right", "#d62728"),
            (x, [lengths[n]["subject_mm"] for n in single], "subject", "#2a7a2a"))
    fig = {"data": [{"type": "bar", "x": bx, "y": by, "name": name, "marker": {"color": colour}}
                    for bx, by, name, colour in bars],
           "layout": {"barmode": "group", "yaxis": {"title": _title("mm")},
                      "title": _title("segment lengths (mm): base model vs subject, left and right side by side")}}
    rows = []
    for p, a_mm, b_mm in zip(pairs, left, right, strict=True):
        rows.append([lengths[p + "_l"]["segment"][:-2], p, f"{lengths[p + '_l']['base_mm']:.1f}", f"{a_mm:.1f}",
                     f"{b_mm:.1f}", f"{100 * abs(a_mm - b_mm) / (0.5 * (a_mm + b_mm)):.1f}"])
    rows += [[lengths[n]["segment"], n, f"{lengths[n]['base_mm']:.1f}", f"{lengths[n]['subject_mm']:.1f}", "", ""]
             for n in single]
    return ("<h2 id=segments>Segment lengths</h2>" + _figure(fig, template, 400)
            + _table(["segment", "to joint", "base (mm)", "subject left / one (mm)", "subject right (mm)",
                      "left/right difference (%)"], rows, {2, 3, 4, 5}))


#: mm: segments shorter than this on either side are left out of the headline left/right difference (their share
#: is of a few mm: Hamner2010's ulna, 50 / 56 mm between the elbow and the radioulnar joint, read 10 %)
SHORT_SEGMENT_MM = 100.0


def longest_asymmetry(lengths: dict) -> tuple[str, dict] | None:
    """The (segment, row) of symmetry_table's segment_length with the largest relative difference among the segments
    at least SHORT_SEGMENT_MM long on both sides (all of them where none is)."""
    long = {k: v for k, v in lengths.items() if min(v["left_mm"], v["right_mm"]) >= SHORT_SEGMENT_MM} or lengths
    return max(long.items(), key=lambda kv: kv[1]["difference"], default=None)


def asymmetry_clause(lengths: dict) -> str:
    """What the summary and the page say of symmetry_table's segment_length rows after "segment lengths differ by up
    to": the largest relative difference (longest_asymmetry) among the segments whose difference the trials measure
    (its posterior SD at most IDENTIFIED times the priors' alone), with its SD; and, where larger, the largest of those
    they leave to the priors and the gauges, said as such (a foot's length ends at centres no marker places:
    Expert1's feet 13 % apart, 24 +- 17 mm, the priors' SD alone 17).  A row without SDs beside rows with them is a
    pair held at the base model's (hold_segments: its difference is the base model's, not the subject's) and is left
    out; in a report without SDs (written before them) every row counts as measured.  Empty without rows."""
    def said(item: tuple[str, dict]) -> str:
        name, row = item
        sd = row.get("difference_sd_mm")
        return (f"{100 * row['difference']:.1f} % ({name}, {abs(row['left_mm'] - row['right_mm']):.1f}"
                + ("" if sd is None else f" +- {sd:.1f}") + " mm)")

    if any("difference_sd_mm" in v for v in lengths.values()):
        lengths = {k: v for k, v in lengths.items() if "difference_sd_mm" in v}
    head = longest_asymmetry({k: v for k, v in lengths.items() if v.get("measured", True)})
    worst = longest_asymmetry(lengths)
    return _split_clause(head and head[0], worst and worst[0], lambda k: lengths[k]["difference"],
                         lambda k: said((k, lengths[k])), lambda k: lengths[k]["priors_sd_mm"], "; ")


def mirror_clause(sym: Mapping) -> str:
    """What the summary and the page say of symmetry_table's mirrored centres after "mirrored centres by up to": the
    largest distance between a left centre and its mirrored right partner among those the trials measure (the
    distance's posterior SD at most IDENTIFIED times the priors' alone: centre_mirror_sd), with its SD; and, where
    larger, the largest of those they leave to the priors, said as such (a forearm's radioulnar centres, which a walk
    does not place); a pair without SDs beside pairs with them is held at the base model's and left out.  A report
    without the SDs: the largest, as it stands.  Empty without pairs."""
    dist, sds = sym.get("centre_mirror_mm") or {}, sym.get("centre_mirror_sd") or {}
    if sds:
        dist = {k: v for k, v in dist.items() if k in sds}

    def said(name: str) -> str:
        sd = sds.get(name, {}).get("sd_mm")
        return f"{dist[name]:.1f}" + ("" if sd is None else f" +- {sd:.1f}") + f" mm ({name})"

    measured = [k for k in dist if sds.get(k, {}).get("measured", True)]
    return _split_clause(max(measured, key=dist.get, default=None), max(dist, key=dist.get, default=None), dist.get,
                         said, lambda k: sds[k]["priors_sd_mm"], ", ")


def _split_clause(head: str | None, worst: str | None, size: Callable[[str], float], said: Callable[[str], str],
                  priors_sd: Callable[[str], float], sep: str) -> str:
    """The clause of asymmetry_clause and mirror_clause: `head` (the largest the trials measure) said, and `worst`
    (the largest of all, by `size`) after it as left to the priors where it is another and larger (`sep` between);
    `worst` alone, so named, where none is measured; empty where there is none."""
    if worst is None:
        return ""
    if head is None:
        return said(worst) + ", left to the priors"
    if worst != head and size(worst) > size(head):
        return (f"{said(head)} measured by the trials{sep}{said(worst)} left to the priors "
                f"(SD {priors_sd(worst):.1f} mm alone)")
    return said(head)


def seed_note_groups(notes: Sequence[str], taken: bool) -> tuple[list[str], list[str], list[str]]:
    """The seed's notes as (shown before, moot, shown after): where the start did not take the MTB seed (Seed.taken)
    and it has more than three notes, its own notes between the 'seeded from' one and the start's choice are moot
    (the summary counts them, the HTML report folds them); otherwise every note is shown."""
    notes = list(notes)
    if taken or len(notes) <= 3:
        return notes, [], []
    first = notes[:1] if notes[0].startswith("seeded from") else []
    return first, notes[len(first):-1], notes[-1:]


def report_html(report: Mapping, title: str | None = None) -> str:
    """The HTML report (one self-contained page, module docstring) of a report JSON's content."""
    try:
        import plotly
        import plotly.io as pio
    except ImportError:  # pragma: no cover - plotly is a dependency
        raise CalibrateError("the HTML report needs plotly: pip install plotly") from None
    rep = dict(report)
    for key in ("trials", "markers", "solver", "parameters", "model", "outliers", "settings"):
        if key not in rep:
            raise CalibrateError(f"not a calibrate report: it has no '{key}' (give the _report.json a calibration "
                                 "wrote)")
    name = title or (rep["trials"][0]["source"] if rep["trials"] and rep["trials"][0]["source"] else "calibration")
    template = pio.templates["plotly_white"].to_plotly_json()  # what plotly's figures carry, made once a page
    body = [f"<h1>calibrate report: {_e(name)}</h1>",
            "<p class=muted><a href=#notes>notes</a> · <a href=#summary>summary</a> · <a href=#markers>marker "
            "errors</a> · <a href=#angles>joint angles</a> · <a href=#parameters>parameters</a> · "
            "<a href=#segments>segment lengths</a></p>",
            _notes(rep), _summary(rep), _marker_figures(rep, template), _angle_figures(rep, template),
            _parameters(rep, template), _segments(rep, template)]
    js = plotly.offline.get_plotlyjs()
    # the figures' random element ids numbered instead: the same report gives the same page
    ids: dict[str, str] = {}
    page = re.sub(_UUID, lambda m: ids.setdefault(m.group(0), f"figure-{len(ids) + 1}"), "".join(body))
    return ("<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
            f"<title>calibrate report: {_e(name)}</title><style>{STYLE}</style>"
            f"<script type=\"text/javascript\">{js}</script></head><body>" + page + "</body></html>\n")


def read_report(path: Path) -> dict:
    """A report JSON, or CalibrateError (one line) saying what is wrong with the file."""
    try:
        rep = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise CalibrateError(f"{path}: no such file; give the _report.json a calibration wrote") from None
    except (OSError, UnicodeDecodeError) as e:
        raise CalibrateError(f"{path}: cannot read ({e}); give the _report.json a calibration wrote") from None
    except json.JSONDecodeError as e:
        raise CalibrateError(f"{path}: not JSON (line {e.lineno}: {e.msg}); give the _report.json a calibration "
                             "wrote") from None
    if not isinstance(rep, dict) or "parameters" not in rep or "trials" not in rep:
        raise CalibrateError(f"{path}: not a calibrate report (no 'parameters' or 'trials'); give the _report.json "
                             "a calibration wrote")
    return rep


def write_report_html(report: Mapping, path, overwrite: bool = False, title: str | None = None) -> Path:
    """Write the HTML report of `report` (a report JSON's content) to `path`, all or nothing
    (calibrate.io.outputs); refuses an existing file unless `overwrite`."""
    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise CalibrateError(f"{path}: the HTML report needs an .html name")
    check_targets([path], overwrite)
    text = report_html(report, title)
    write_all({path: lambda staged: put_text(staged, text)})
    return path
