"""The HTML report (calibrate.calibration.html), the report JSON's series, `calibrate report`,
`--html`, the 3-D view's rerun recording read back, and the progress bars: on a small simulated
calibration (squats with spiked marker samples, so positions are rejected)."""

from __future__ import annotations

import html
import importlib.util
import io
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from calibrate.calibration.html import report_html
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.records import Progress
from calibrate.calibration.series import trial_series
from calibrate.cli.main import main
from calibrate.io.read import read_trial
from calibrate.model.blocks import FrameLayout
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model
from calibrate.simulation import simulate_squats, write_simulation
from calibrate.solve.ik import marker_columns

MODEL = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
FRAMES = 40


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A calibration of a simulated 40-frame squat trial (3 spikes), written with its HTML report."""
    d = tmp_path_factory.mktemp("html")
    model = load_model(MODEL)
    sim = simulate_squats(model, frames=FRAMES, noise_mm=1.0, seed=7, spikes=3)
    paths = write_simulation(sim, d)
    trial = read_trial(paths["trial"])
    cal = calibrate(model, trial)
    out = {"urdf": d / "subject.urdf", "motion": d / "subject_motion.csv", "report": d / "subject_report.json",
           "html": d / "subject.html"}
    cal.write(**out)
    return {"dir": d, "sim": sim, "cal": cal, "trial": trial, "model": model,
            **out, "rep": json.loads(out["report"].read_text())}


def test_series_residuals_are_the_model_markers_minus_the_trial(run):
    """The JSON's per-marker residual norms: model markers (forward kinematics of the written motion and
    parameters) minus the trial's markers, computed here afresh."""
    cal, rep = run["cal"], run["rep"]
    ts = rep["series"]["trials"][0]
    assert ts["frames"] == list(range(FRAMES)) and ts["block"] == 1
    kin = build_kinematics(cal.model)
    mo = cal.motion
    M, _ = kin.batch(FrameLayout.coordinates(mo.root_translation, mo.angles), mo.root_quaternion, cal.params)
    obs = marker_columns(cal.model, run["trial"])
    err = 1000 * np.linalg.norm(M - obs, axis=2)
    rejected = {(o["frame"], o["marker"]) for o in rep["outliers"]["rejected"]}
    checked = 0
    for k, name in enumerate(cal.model.marker_names):
        got = ts["residual_mm"].get(name)
        if got is None:
            continue
        for f in range(FRAMES):
            if got[f] is None or (f, name) in rejected:
                continue
            assert abs(got[f] - err[f, k]) < 0.06, (name, f)
            checked += 1
    assert checked > 0.9 * FRAMES * len(ts["residual_mm"])
    # joint angles: the motion CSV's, in degrees
    for k, dof in enumerate(mo.dof_names):
        np.testing.assert_allclose(ts["angles_deg"][dof], np.degrees(mo.angles[:, k]), atol=0.006)
    # the base model's limits
    for dof in run["model"].dofs:
        lo, hi = rep["series"]["limits_deg"][dof.name]
        if np.isfinite(dof.lower):
            assert lo == pytest.approx(np.degrees(dof.lower), abs=1e-3)
            assert hi == pytest.approx(np.degrees(dof.upper), abs=1e-3)


def test_series_blocks_keep_the_largest_residual(run):
    """A long trial is cut into blocks: each block's value is the largest residual in it (brute force)."""
    cal = run["cal"]
    ts = trial_series(cal, 0, max_points=7)
    err = 1000 * np.linalg.norm(cal.residuals, axis=2)
    step = ts["block"]
    assert step == 6 and ts["frames"] == list(range(0, FRAMES, 6)) and len(ts["frames"]) <= 7
    for k, name in enumerate(cal.model.marker_names):
        if name not in ts["residual_mm"]:
            continue
        for b, start in enumerate(ts["frames"]):
            block = err[start:start + step, k]
            want = np.nanmax(block) if np.isfinite(block).any() else None
            got = ts["residual_mm"][name][b]
            assert (got is None and want is None) or abs(got - want) < 0.06


def test_segment_lengths_are_distances_between_joint_centres(run):
    """Subject segment lengths: the world distance between the centres of a segment's two joints."""
    cal, rep = run["cal"], run["rep"]
    lengths = rep["series"]["segment_lengths"]
    kin = build_kinematics(cal.model)
    mo = cal.motion
    _, C = kin.batch(FrameLayout.coordinates(mo.root_translation, mo.angles), mo.root_quaternion, cal.params)
    names = [j.name for j in cal.model.joints]
    base = load_model(MODEL)
    into = {j.child: j.name for j in cal.model.joints}  # the joint into each segment
    checked = 0
    for name, entry in lengths.items():
        upper = into.get(entry["segment"])
        if upper is None:  # the root segment: its origin is no joint centre
            continue
        d = 1000 * np.linalg.norm(C[:, names.index(name)] - C[:, names.index(upper)], axis=1)
        assert entry["subject_mm"] == pytest.approx(float(np.median(d)), abs=0.5), name
        assert np.ptp(d) < 0.5  # a rigid segment
        j = base.joints[base.joint_index(name)]
        assert entry["base_mm"] == pytest.approx(1000 * np.linalg.norm(j.centre), abs=0.01)
        checked += 1
    assert checked >= 10


def test_the_left_right_headline_leaves_short_segments_out(run):
    """The summary's and the HTML's left/right line name the largest relative length difference among segments at
    least SHORT_SEGMENT_MM long on both sides, with its mm and the difference's posterior SD (a 5 mm difference of a
    50 mm ulna read 10 %): recomputed here from the report's symmetry rows; a short segment's larger share does not
    take the headline.  A larger difference the trials leave to the priors (its SD as the priors' alone) is said as
    such after the measured one, and alone when none is measured."""
    from calibrate.calibration.html import SHORT_SEGMENT_MM, asymmetry_clause, longest_asymmetry, mirror_clause
    from calibrate.calibration.report import summary_text

    cal, rep = run["cal"], run["rep"]
    rows = rep["symmetry"]["segment_length"]

    def largest(among: dict) -> str:
        return max(among, key=lambda k: abs(among[k]["left_mm"] - among[k]["right_mm"]) / np.mean(
            [among[k]["left_mm"], among[k]["right_mm"]]))

    def said(name: str, row: dict) -> str:
        mm = abs(row["left_mm"] - row["right_mm"])
        return f"{100 * row['difference']:.1f} % ({name}, {mm:.1f} +- {row['difference_sd_mm']:.1f} mm)"

    longer = {k: v for k, v in rows.items() if min(v["left_mm"], v["right_mm"]) >= SHORT_SEGMENT_MM}
    long = {k: v for k, v in longer.items() if v["measured"]}
    for k, v in rows.items():  # measured: the difference's posterior SD at most half the priors' alone
        assert v["measured"] == (v["difference_sd_mm"] <= 0.5 * v["priors_sd_mm"]), (k, v)
    if long:  # the largest the trials measure heads the line
        name = largest(long)
        want = "segment lengths differ by up to " + said(name, long[name])
    else:  # none measured (this 40-frame squat's femurs sit at the edge): the largest, left to the priors
        name = largest(longer)
        want = "segment lengths differ by up to " + said(name, longer[name]) + ", left to the priors"
    assert want in summary_text(cal) and want in report_html(rep)
    # The clause's rules on rows made here: a measured femur, a short ulna, a foot left to the priors.
    name = "femur"
    long = {name: {"left_mm": 485.1, "right_mm": 469.3, "difference": 0.0331, "difference_sd_mm": 8.7,
                   "priors_sd_mm": 17.4, "measured": True}}
    want = "segment lengths differ by up to " + said(name, long[name])
    short = {**long, "ulna": {"left_mm": 50.5, "right_mm": 55.9, "difference": 0.101}}
    assert longest_asymmetry(short)[0] == name
    assert longest_asymmetry({"ulna": short["ulna"]})[0] == "ulna"  # nothing longer: the short one
    foot = {"left_mm": 170.5, "right_mm": 194.7, "difference": 0.1323, "difference_sd_mm": 16.6,
            "priors_sd_mm": 16.6, "measured": False}
    assert asymmetry_clause({**long, "calcn": foot}) == (
        want.removeprefix("segment lengths differ by up to ") + " measured by the trials; 13.2 % (calcn, "
        "24.2 +- 16.6 mm) left to the priors (SD 16.6 mm alone)")
    alone = asymmetry_clause({"calcn": foot})
    assert alone == "13.2 % (calcn, 24.2 +- 16.6 mm), left to the priors"
    held = {"left_mm": 236.4, "right_mm": 236.4, "difference": 0.0}  # a pair held at the base model's: no SDs
    assert asymmetry_clause({"calcn": foot, "radius": held}) == alone
    assert asymmetry_clause({"radius": held}) == "0.0 % (radius, 0.0 mm)"  # a report without SDs: as it stands
    # The mirrored centres' clause: the largest the trials measure, with its SD, then a larger one left to the priors.
    dist = {"hip": 20.6, "knee": 23.5, "wrist": 1.0}
    sds = {"hip": {"sd_mm": 5.0, "priors_sd_mm": 14.0, "measured": True},
           "knee": {"sd_mm": 9.8, "priors_sd_mm": 17.2, "measured": False}}
    assert mirror_clause({"centre_mirror_mm": dist, "centre_mirror_sd": sds}) == (
        "20.6 +- 5.0 mm (hip) measured by the trials, 23.5 +- 9.8 mm (knee) left to the priors (SD 17.2 mm alone)")
    assert mirror_clause({"centre_mirror_mm": {"knee": 23.5}, "centre_mirror_sd": sds}) == (
        "23.5 +- 9.8 mm (knee), left to the priors")
    assert mirror_clause({"centre_mirror_mm": dist}) == "23.5 mm (knee)"  # a report without the SDs
    assert mirror_clause({"centre_mirror_mm": {**dist, "radioulnar": 40.0}, "centre_mirror_sd": sds}) == (
        "20.6 +- 5.0 mm (hip) measured by the trials, 23.5 +- 9.8 mm (knee) left to the priors (SD 17.2 mm alone)")
    sym = rep["symmetry"]
    assert f"mirrored centres by up to {mirror_clause(sym)}" in summary_text(cal)
    assert f"mirrored centres by up to {mirror_clause(sym)}" in report_html(rep)


def test_the_left_right_sds_follow_the_lengths_and_centres_by_finite_differences(run):
    """identifiability.length_differences and mirror_differences against finite differences: each free parameter of
    the calibrated subject stepped on its manifold (Problem.retract_parameters, the solve's own step: a scale step
    keeps its segment's offsets at the subject's scale), the two sides' lengths (and the mirrored centres' distances)
    recomputed from the unpacked parameters, and their SDs propagated through a random covariance; and the report's
    rows carry the pipeline's."""
    from calibrate.calibration.identifiability import length_differences, mirror_differences, segment_end
    from calibrate.problem.priors import symmetry_pairs
    from calibrate.problem.problem import Problem

    cal, rep = run["cal"], run["rep"]
    model = cal.model
    problem = Problem(model, np.full((1, len(model.markers), 3), np.nan), cal.settings)
    p = cal.params.vector()
    n = problem.layout.n_free
    R = np.random.default_rng(0).normal(size=(n, n))
    cov, cov0 = R @ R.T * 1e-6, np.eye(n) * 1e-4
    segments, joints, mirror = symmetry_pairs(model, model.parameters().centre)

    def length_difference(P, a: int, b: int) -> float:
        return float(np.subtract(*(np.linalg.norm(P.scale[s] * P.centre[segment_end(model, s)]) for s in (a, b))))

    def mirrored_distance(P, a: int, b: int) -> float:
        sa, sb = (P.scale[model.segment_index(model.joints[j].parent)] for j in (a, b))
        return float(np.linalg.norm(sa * P.centre[a] - mirror * sb * P.centre[b]))

    eps = 1e-6
    ended = [(a, b) for a, b in segments if segment_end(model, a) is not None]
    for sds, pairs, names, quantity in (
            (length_differences(problem, p, cov, cov0), ended, model.segments, length_difference),
            (mirror_differences(problem, p, cov, cov0), joints, model.joints, mirrored_distance)):
        assert len(sds) == len(pairs) >= 4
        for a, b in pairs:
            g = np.array([(quantity(model.unpack(problem.retract_parameters(p, eps * e)), a, b)
                           - quantity(model.unpack(problem.retract_parameters(p, -eps * e)), a, b)) / (2 * eps)
                          for e in np.eye(n)])
            sd, sd0 = sds[names[a].name[:-2]]
            assert sd == pytest.approx(np.sqrt(g @ cov @ g), rel=1e-5)
            assert sd0 == pytest.approx(np.sqrt(g @ cov0 @ g), rel=1e-5)
    for name, row in rep["symmetry"]["segment_length"].items():
        sd, sd0 = cal.length_sd[name]
        assert row["difference_sd_mm"] == pytest.approx(1000 * sd) and row["priors_sd_mm"] == pytest.approx(1000 * sd0)
        assert row["measured"] == (sd <= 0.5 * sd0)
    for name, row in rep["symmetry"]["centre_mirror_sd"].items():
        sd, sd0 = cal.mirror_sd[name]
        assert row["sd_mm"] == pytest.approx(1000 * sd) and row["measured"] == (sd <= 0.5 * sd0)


def _plot_data(page: str) -> list[dict]:
    """The traces of every plotly figure of a page."""
    traces = []
    body = page[page.index("</head>"):]
    for m in re.finditer(r'Plotly\.newPlot\(\s*"figure-\d+",\s*(\[.*?\]),\s*\{"template"', body, re.S):
        traces += json.loads(m.group(1))
    return traces


def test_html_report_has_its_tables_and_figures(run):
    rep = run["rep"]
    page = run["html"].read_text()
    assert page == report_html(rep)  # the file written beside the JSON is the JSON's report
    # self-contained: plotly.js inside, nothing fetched
    head, body = page[:page.index("<script")], page[page.index("</head>"):]
    assert page.count("<script type=\"text/javascript\">") == 1 and len(page) > 3_000_000  # plotly.js, once
    for part in (head, body):
        assert not re.search(r"<(script|link|img|iframe)\b[^>]*\b(src|href)=", part)
    # the notes come first, then the sections in order
    order = [page.index(f"id={s}>") for s in ("notes", "summary", "markers", "angles", "parameters", "segments")]
    assert order == sorted(order)
    for note in rep["notes"]:
        assert note.split(":")[0] in page[order[0]:order[1]]
    # summary table: the trial's RMS and the iterations
    assert f"{rep['trials'][0]['rms_mm']:.2f}" in page
    assert f"{rep['solver']['iterations']} ({rep['solver']['accepted_steps']} accepted)" in page
    assert f"{rep['subject_size']:.3f} x the base model" in page  # the subject's size, the scales' mean
    sw = rep["software"]  # the versions the result went through, in the summary
    assert f"{sw['calibrate']} (Python {sw['python']}; casadi {sw['casadi']}, pinocchio {sw['pinocchio']}," in page
    traces = _plot_data(page)
    kinds = [t.get("type") for t in traces]
    bars = [t for t in traces if t.get("type") == "bar"]
    # marker RMS bars: every marker with its RMS
    rms = bars[0]
    assert sorted(rms["x"]) == sorted(rep["markers"]["per_marker"])
    for x, y in zip(rms["x"], rms["y"], strict=True):
        assert y == pytest.approx(rep["markers"]["per_marker"][x]["rms_mm"])
    # heat map marker x time, the rejected positions marked
    heat = next(t for t in traces if t.get("type") == "heatmap")
    assert len(heat["x"]) == FRAMES and set(heat["y"]) == set(rep["series"]["trials"][0]["residual_mm"])
    assert rep["outliers"]["count"] >= 1
    rej = next(t for t in traces if t.get("name") == "rejected")
    assert sorted(rej["y"]) == sorted(o["marker"] for o in rep["outliers"]["rejected"])
    # residual curves per marker, joint-angle curves per coordinate with their limits shaded
    names = {t.get("name") for t in traces if t.get("type") == "scatter"}
    assert set(rep["series"]["trials"][0]["residual_mm"]) <= names
    assert set(rep["series"]["trials"][0]["angles_deg"]) <= names
    shaded = [t for t in traces if t.get("fill") == "toself"]
    assert len(shaded) == sum(1 for lo, hi in rep["series"]["limits_deg"].values() if lo is not None)
    # parameters: every one in the table with its SD and identifiability; bars per group
    for p in rep["parameters"]:
        assert f"<td>{p['name']}</td>" in page
    assert any(set(b["x"]) == {p["name"] for p in rep["parameters"] if p["group"] == "centre"} for b in bars)
    assert "no (prior)" in page and ">yes<" in page
    # segment lengths: left and right side by side
    left = next(t for t in bars if t.get("name") == "subject left")
    right = next(t for t in bars if t.get("name") == "subject right")
    assert left["x"] == right["x"] and len(left["x"]) >= 4
    assert "heatmap" in kinds


def test_a_label_to_check_is_among_the_notes(run):
    """A report's suspect label (Calibration.misplaced, as the report JSON carries it) is a note of the HTML
    report, before the summary, with the segment it moves with and its own segment's labels."""
    rep = dict(run["rep"], suspect_labels=[{"trial": "walk.c3d", "label": "RKNE", "segment": "femur_r",
                                            "moves_with": "calcn_r", "segment_labels": ["RTHI"],
                                            "distance_sd_own_mm": 81.0, "distance_sd_other_mm": 4.0}])
    page = report_html(rep)
    notes = page[page.index("id=notes>"):page.index("id=summary>")]
    assert "check label RKNE (walk.c3d): it moves with calcn_r's markers" in notes and "(RTHI: 81.0 mm)" in notes
    assert "check label" not in report_html(run["rep"])  # the calibration's own labels raised none


def test_implausible_hips_and_centres_are_marked_bad_among_the_notes(run):
    """What the summary calls implausible reads so in the HTML report's notes: a hip the trials do not place that
    ended far from Harrington's regression (pig_walk, OpenCap's and Expert1's walks: a plain note before), and a
    centre or axis a trade carried far (`implausible_flags`' centre[...] / axis[...]: no note before)."""
    hips = [dict(joint="hip_l", range_deg={"hip_l_flexion": 43.0}, places_centre=False, from_regression_mm=65.0,
                 implausible=True, hip_width_mm=250.0, asis_width_mm=240.0, from_model_mm=60.0, model_offset_mm=7.5,
                 as_model=False),
            dict(joint="hip_r", range_deg={"hip_r_flexion": 43.0}, places_centre=False, from_regression_mm=9.0,
                 implausible=False, hip_width_mm=250.0, asis_width_mm=240.0, from_model_mm=8.0, model_offset_mm=7.5,
                 as_model=False)]
    flag = "centre[hip_l]: the trial places it (posterior SD 3 mm), yet 64 mm from where its prior puts it"
    page = report_html(dict(run["rep"], hip_motion=hips, implausible_flags=[flag]))
    notes = page[page.index("id=notes>"):page.index("id=summary>")]
    bad = re.findall(r"<li class=bad>(.*?)</li>", notes, re.S)
    assert any(b.startswith("hip_l: the trials turn it through") and "65 mm from Harrington" in b for b in bad)
    assert not any(b.startswith("hip_r") for b in bad) and "<li>hip_r: the trials turn it through" in notes
    assert f"implausible {flag}" in bad
    assert "implausible centre[" not in report_html(dict(run["rep"], implausible_flags=[]))


def test_an_unreliable_parameter_is_marked_so_in_the_table_and_the_bars(run):
    """A parameter the report calls unreliable (far beyond its prior, identified or not) reads so in the
    parameters table and its bar is red, not "held by prior" (gait2392's back centre with its IK setup)."""
    params = [dict(p) for p in run["rep"]["parameters"]]
    centre = next(p for p in params if p["group"] == "centre")
    centre.update(identified=False, unreliable=True)
    page = report_html(dict(run["rep"], parameters=params))
    row = page[page.index(f"<td>{centre['name']}</td>"):]
    assert row[:row.index("</tr>")].count("<td>no (unreliable)</td>") == 1
    bars = [t for t in _plot_data(page) if t.get("type") == "bar" and centre["name"] in t.get("x", [])]
    k = bars[0]["x"].index(centre["name"])
    assert bars[0]["marker"]["color"][k] == "#b02020" and bars[0]["hovertext"][k] == "identified: no (unreliable)"


def test_the_seed_notes_of_a_seed_the_start_did_not_take_are_folded(run):
    """The race takes the MTB seed on the simulated subject (Seed.taken, by the geometry the start began from; the
    report's seed says so).  Where it takes the base model instead (pig_walk: 20 MTB seed notes), the summary and
    the HTML fold what the seed could not place under one line; the report JSON keeps every note."""
    from dataclasses import replace

    from calibrate.calibration.report import calibration_report, summary_text

    cal = run["cal"]
    assert cal.seed.taken and run["rep"]["seed"]["taken"] is True
    assert cal.seed.notes[-1].startswith("started from the MTB seed")
    notes = ("seeded from walk.c3d (the trial with the most joint motion)",
             *(f"knee_{s}: seeded axis more than 30 deg from the base model's; base model axis used" for s in "lr"),
             "ankle_l: joint-centre seed too uncertain; base model used",
             "started from the base model: of the MTB seed (cost 2e5), the base model (cost 1e5), its basin fits best")
    other = replace(cal, seed=replace(cal.seed, notes=notes, taken=False))
    lines = [x for x in summary_text(other).splitlines() if x.startswith("  seed: ")]
    assert lines == ["  seed: " + notes[0],
                     "  seed: 3 notes on the MTB seed, moot: the start did not take it (the report's seed notes)",
                     "  seed: " + notes[-1]]
    rep = calibration_report(other)
    assert rep["seed"]["notes"] == list(notes) and rep["seed"]["taken"] is False
    page = report_html(rep)
    folded = page[page.index("what the MTB seed could not place (moot"):]
    assert all(html.escape(n) in folded[:folded.index("</ul>")] for n in notes[1:-1])
    assert html.escape(notes[-1]) in folded
    taken = [x for x in summary_text(cal).splitlines() if x.startswith("  seed: ")]
    assert taken == ["  seed: " + n for n in cal.seed.notes]


def test_left_out_labels_are_among_the_notes_with_their_reasons(run):
    """Trial labels left out (the report JSON's marker_set.left_out) are a note of the HTML report, each with its
    own reason; the clause every reason shares (the segments that carry no markers) is said once."""
    from calibrate.seed.association import UNMARKED

    clause = UNMARKED.format("talus_l, talus_r")
    left = [{"label": "LOOSE1", "reason": "varies by 5.3 mm std or more; " + clause},
            {"label": "LOOSE2", "reason": "never seen long enough together with any model marker; " + clause}]
    rep = dict(run["rep"], marker_set=dict(run["rep"]["marker_set"], left_out=left))
    page = report_html(rep)
    notes = page[page.index("id=notes>"):page.index("id=summary>")]
    assert f"2 trial labels left out ({clause}):" in notes and notes.count("cannot receive markers") == 1
    assert "<li>LOOSE1: varies by 5.3 mm std or more</li>" in notes
    assert "<li>LOOSE2: never seen long enough together with any model marker</li>" in notes
    # Reasons without the shared clause are shown whole; the calibration's own trial left none out.
    rep = dict(run["rep"], marker_set=dict(run["rep"]["marker_set"], left_out=[{"label": "X", "reason": "a; b"}]))
    assert "<li>X: a; b</li>" in report_html(rep)
    page = report_html(run["rep"])
    assert "trial labels left out" not in page[page.index("id=notes>"):page.index("id=summary>")]


@pytest.mark.skipif(shutil.which("chromium") is None and not Path("/usr/bin/chromium").exists(),
                    reason="chromium is not installed (Debian: apt-get install chromium)")
def test_chromium_renders_the_report(run, tmp_path):
    """Headless Chromium renders the page offline; the screenshot is not blank."""
    from PIL import Image

    exe = shutil.which("chromium") or "/usr/bin/chromium"
    shot = tmp_path / "shot.png"
    subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    "--virtual-time-budget=10000", f"--screenshot={shot}", "--window-size=1200,2400",
                    run["html"].as_uri()], check=True, capture_output=True, timeout=120)
    img = np.asarray(Image.open(shot).convert("L"), dtype=float)
    assert img.shape == (2400, 1200)
    assert img.std() > 20  # not a blank page
    assert (img < 200).mean() > 0.03  # text and figures drawn
    # the figures drew: coloured pixels (bars, heat map), not only black text on white
    rgb = np.asarray(Image.open(shot).convert("RGB"), dtype=float)
    assert (rgb.max(axis=2) - rgb.min(axis=2) > 60).mean() > 0.02


def test_cli_report_from_the_json(run, tmp_path):
    out = tmp_path / "r.html"
    assert main(["report", str(run["report"]), "-o", str(out)]) == 0
    assert out.read_text() == report_html(json.loads(run["report"].read_text()))
    before = out.stat().st_mtime_ns
    assert main(["report", str(run["report"]), "-o", str(out)]) == 2  # exists: refused, untouched
    assert out.stat().st_mtime_ns == before
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    assert main(["report", str(bad), "-o", str(tmp_path / "b.html")]) == 2
    assert not (tmp_path / "b.html").exists()
    assert main(["report", str(run["report"]), "-o", str(tmp_path / "r.txt")]) == 2
    # a report written before the series: the tables still, the figures it can draw
    old = {k: v for k, v in run["rep"].items() if k != "series"}
    page = report_html(old)
    assert "made by an older calibrate" in page and all(f"<td>{p['name']}</td>" in page for p in old["parameters"])
    (tmp_path / "no.json").write_text(json.dumps({"trials": []}))
    assert main(["report", str(tmp_path / "no.json"), "-o", str(tmp_path / "no.html")]) == 2
    assert not (tmp_path / "no.html").exists()


def test_cli_calibrate_html_flag(run, tmp_path, capsys, monkeypatch):
    """`--html` beside the other outputs; the view found the files of a report written with relative
    names from another folder."""
    (tmp_path / "lab").mkdir()
    trial = tmp_path / "lab" / "t.c3d"
    shutil.copy(run["dir"] / "trial.c3d", trial)
    monkeypatch.chdir(tmp_path)
    assert main(["lab/t.c3d", str(MODEL), "--html", "lab/t.html", "-q"]) in (0, 1)
    rep = json.loads((tmp_path / "lab" / "t_report.json").read_text())
    assert rep["outputs"]["html"] == "lab/t.html"
    page = (tmp_path / "lab" / "t.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "id=segments>" in page
    monkeypatch.chdir(tmp_path / "lab")  # the report's relative names do not hold from here
    if importlib.util.find_spec("rerun") is not None:
        assert main(["view", "t_report.json", "--rrd", "t.rrd"]) == 0
        assert len(_rrd_points(tmp_path / "lab" / "t.rrd", "/markers/measured")) == FRAMES
    trial = tmp_path / "lab" / "t.c3d"
    # a wrong name is refused before any work, nothing written
    assert main([str(trial), str(MODEL), "--html", str(tmp_path / "x.pdf"), "--overwrite"]) == 2
    assert "needs an .html name" in capsys.readouterr().err


def _rrd_points(path: Path, entity: str) -> list[np.ndarray]:
    """Per frame (by the 'frame' timeline), the Points3D positions logged at `entity` in a .rrd file."""
    chunk = pytest.importorskip("rerun.chunk")
    frames: dict[int, np.ndarray] = {}
    for c in chunk.RrdReader(path).stream():
        if str(c.entity_path) != entity:
            continue
        b = c.to_record_batch()
        names = b.schema.names
        col = b.column(names.index("Points3D:positions")).to_pylist()
        for f, pos in zip(b.column(names.index("frame")).to_pylist(), col, strict=True):
            frames[f] = np.array(pos, dtype=float).reshape(-1, 3)
    return [frames[f] for f in sorted(frames)]


def test_rerun_recording_read_back(run, tmp_path):
    """The recording `calibrate view --rrd` saves: per frame the trial's measured markers (as the
    simulator wrote them), the model's markers and every joint centre."""
    pytest.importorskip("rerun")
    out = tmp_path / "v.rrd"
    assert main(["view", str(run["report"]), "--rrd", str(out)]) == 0
    measured = _rrd_points(out, "/markers/measured")
    joints = _rrd_points(out, "/skeleton/joints")
    model_markers = _rrd_points(out, "/markers/model")
    assert len(measured) == len(joints) == len(model_markers) == FRAMES
    trial = run["sim"].trial
    for f in (0, FRAMES // 2, FRAMES - 1):
        want = trial.markers[f][np.isfinite(trial.markers[f]).all(axis=1)]
        np.testing.assert_allclose(np.sort(measured[f], axis=0), np.sort(want, axis=0), atol=1e-5)
        assert joints[f].shape == (len(run["cal"].model.joints), 3)
    # the model markers are the calibration's: trial + residual where seen
    cal = run["cal"]
    f = FRAMES // 2
    seen = np.isfinite(cal.residuals[f]).all(axis=1)
    obs = marker_columns(cal.model, run["trial"])[f]
    np.testing.assert_allclose(model_markers[f][seen], obs[seen] + cal.residuals[f][seen], atol=1e-4)
    assert main(["view", str(run["report"]), "--rrd", str(out)]) == 2  # exists: refused


def test_countdown_times_what_is_left_from_the_first_share_told(monkeypatch):
    """Countdown's time left runs at the rate since the first share was told, not since it was made (the step's
    set-up before its first frame: `calibrate ik` said "about 16 s left" of a 2 s trial); nothing in its first
    second, nothing at 0 or 1."""
    from calibrate.calibration import records

    clock = iter([0.0, 0.9, 1.1, 1.5, 2.5])  # made; the first share; then shares told
    monkeypatch.setattr(records.time, "perf_counter", lambda: next(clock))
    said = []
    count = records.Countdown(said.append, "ik", "fitting", every=0.1)
    count(0.05)  # at 0.9 s: the first share, within the first second
    count(0.25)  # at 1.1 s: 0.2 of the work in 0.2 s, 0.75 left
    count(1.0)  # at 1.5 s: done, nothing said
    assert [str(m) for m in said] == ["ik: fitting 25 % (about 1 s left)"]


def test_progress_bars_on_a_terminal_plain_lines_otherwise():
    from calibrate.cli.commands import Timed
    from calibrate.cli.report import Bars, progress_for

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    term = Terminal()
    with progress_for(False, 20, Timed, term) as say:
        assert isinstance(say, Bars)
        say(Progress("seed", "joint centres by MTB"))
        for i in range(1, 6):
            say(Progress("solve", f"iteration {i} cost 1.0", iteration=i))
    text = term.getvalue()  # the solve's bar ends at the iterations it took (5/5)
    assert "seed: joint centres by MTB" in text and "solve: iteration 5" in text and "5/5" in text
    with progress_for(False, 20, Timed, io.StringIO()) as say:
        assert isinstance(say, Timed)
    with progress_for(True, 20, Timed, term) as say:
        assert not isinstance(say, (Bars, Timed))


def test_the_summary_names_a_dozen_unseen_model_markers_and_counts_the_rest(run):
    """A model carrying many markers the trials never show (Rajagopal2016 beside its walk: 90): the summary counts
    them and names the first UNUSED_SHOWN, the report keeps every name; a few are all named."""
    from dataclasses import replace

    from calibrate.calibration.report import UNUSED_SHOWN, calibration_report, summary_text

    names = tuple(run["cal"].model.marker_names)
    many = replace(run["cal"], unused_markers=names)
    line = next(x for x in summary_text(many).splitlines() if x.startswith("  model markers never seen: "))
    assert line.startswith(f"  model markers never seen: {len(names)} ({', '.join(names[:UNUSED_SHOWN])}, ... and "
                           f"{len(names) - UNUSED_SHOWN} more: the report's marker_set.unused_model_markers")
    assert calibration_report(many)["marker_set"]["unused_model_markers"] == list(names)
    few = replace(run["cal"], unused_markers=names[:2])
    line = next(x for x in summary_text(few).splitlines() if x.startswith("  model markers never seen: "))
    assert line == f"  model markers never seen: 2 ({names[0]}, {names[1]}; base positions kept)"
