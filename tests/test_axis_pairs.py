"""A hinge's axis along the line of two markers straddling its centre (the epicondyles about a knee): found by their
place, drawn by Priors.pair_axis, the centre slid to their midpoint, and reported as the written model shows it."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from conftest import prior_jacobian_by_differences, with_medial_markers

from calibrate.calibration.html import report_html
from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import write_model
from calibrate.problem.options import Priors
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns


@pytest.fixture(scope="module")
def paired(human):
    """human.urdf with a medial knee marker on each femur: the lateral one (LKNE, RKNE) reflected through the plane
    across the knee axis at its centre, then 10 mm further out (a 124 mm knee whose centre lies 5 mm from the
    markers' midpoint towards the lateral one)."""
    return with_medial_markers(human, "knee", "KNE", "KNM", 0.010)


def _pairs(model, trial, **priors):
    problem = Problem(model, marker_columns(model, trial), Settings(priors=Priors(**priors)), build_kinematics(model))
    return problem, [(model.joints[j].name, model.markers[a].name, model.markers[b].name, model.dofs[d].name)
                     for j, a, b, d in problem.pair_terms()]


def _world(model, params, path) -> tuple[pin.Model, pin.Data]:
    """The model written with `params`, read back by Pinocchio and posed at its neutral configuration."""
    pm = pin.buildModelFromUrdf(str(write_model(model, path, params)))
    data = pm.createData()
    q = pin.neutral(pm)
    pin.forwardKinematics(pm, data, q)
    pin.updateFramePlacements(pm, data)
    pin.computeJointJacobians(pm, data, q)
    return pm, data


def _axis(pm, data, joint: str) -> np.ndarray:
    """A hinge's axis in the world (unit), from Pinocchio's Jacobian."""
    j = pm.getJointId(joint)
    w = pin.getJointJacobian(pm, data, j, pin.WORLD)[3:, pm.idx_vs[j]]
    return w / np.linalg.norm(w)


def _against_pair(pm, data, joint: str, m1: str, m2: str) -> tuple[float, float]:
    """The hinge's angle from the two markers' line (deg) and its centre's distance from their midpoint along its
    axis (mm), from Pinocchio's placements (independent of calibrate's parameters)."""
    j = pm.getJointId(joint)
    w = _axis(pm, data, joint)
    x1, x2 = (data.oMf[pm.getFrameId(n)].translation for n in (m1, m2))
    e = (x2 - x1) / np.linalg.norm(x2 - x1)
    return math.degrees(math.acos(min(1.0, abs(float(w @ e))))), 1000 * float(w @ (data.oMi[j].translation
                                                                                      - 0.5 * (x1 + x2)))


def test_the_pairs_are_found_by_their_place_and_their_rows_match_differences(human, paired, tmp_path):
    sim = simulate_squats(paired, frames=3, noise_mm=1.0, seed=4)
    problem, found = _pairs(paired, sim.trial)
    assert sorted(found) == [("knee_l", "LKNE", "LKNM", "knee_l"), ("knee_r", "RKNE", "RKNM", "knee_r")]
    # The lateral knee marker has no partner in human.urdf (the thigh's is 170 mm above the knee); a medial marker
    # the trial does not show gives none; pair_axis 0 is off.
    assert _pairs(human, simulate_squats(human, frames=3, noise_mm=1.0, seed=4).trial)[1] == []
    hidden = sim.trial.markers.copy()
    hidden[:, sim.trial.labels.index("LKNM")] = np.nan
    assert [f[0] for f in _pairs(paired, replace(sim.trial, markers=hidden))[1]] == ["knee_r"]
    off, none = _pairs(paired, sim.trial, pair_axis=0.0)
    assert none == []
    rng = np.random.default_rng(3)
    p = problem.retract_parameters(sim.truth.vector(), 0.03 * rng.normal(size=problem.n_free))
    r, J = problem.prior(p)
    r0 = off.prior(p)[0]
    assert r.size == r0.size + 6
    np.testing.assert_allclose(J, prior_jacobian_by_differences(problem, p), atol=1e-5 * max(1.0, np.abs(J).max()))
    # The pair rows' size is the sine of the angle Pinocchio reads between the written model's axis and markers.
    pm, data = _world(paired, paired.unpack(p), tmp_path / "p.urdf")
    np.testing.assert_array_equal(r[:-6], r0)  # the pair rows come last, the others unchanged
    extra = r[-6:]
    sines = sorted(float(np.linalg.norm(extra[k:k + 3])) * problem.settings.priors.pair_axis for k in (0, 3))
    angles = sorted(math.sin(math.radians(_against_pair(pm, data, f"knee_{s}", f"{s.upper()}KNE",
                                                        f"{s.upper()}KNM")[0])) for s in "lr")
    np.testing.assert_allclose(sines, angles, atol=1e-9)
    # The centre rows: along the axis from the midpoint, at the femur's scale, over priors.width.
    rc, Jc = problem.pair_centre_residuals(p)
    along = sorted(abs(_against_pair(pm, data, f"knee_{s}", f"{s.upper()}KNE", f"{s.upper()}KNM")[1]) for s in "lr")
    np.testing.assert_allclose(sorted(np.abs(rc) * 1000 * problem.settings.priors.width), along, atol=1e-6)
    # The gauge's slide along the axes (calibrate.problem.gauge.slide_centres) takes them in: the knee centres from
    # 24 and 17 mm off their markers' midpoints to 2.4 and 1.9 (8.7 and 6.2 without them), the model's markers
    # where they were.
    slid, slid_off = problem.slide_centres(p), off.slide_centres(p)
    after = np.abs(problem.pair_centre_residuals(slid)[0])
    assert np.all(after < 0.2 * np.abs(rc)) and np.all(after < np.abs(problem.pair_centre_residuals(slid_off)[0]))
    Z, Q = np.zeros((1, paired.nz)), np.array([[1.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(problem.kin.batch(Z, Q, slid)[0], problem.kin.batch(Z, Q, p)[0], atol=1e-12)
    fd = np.zeros_like(Jc)
    for k in range(problem.n_free):
        step = np.zeros(problem.n_free)
        step[k] = 1e-6
        fd[:, k] = (problem.pair_centre_residuals(problem.retract_parameters(p, step))[0]
                    - problem.pair_centre_residuals(problem.retract_parameters(p, -step))[0]) / 2e-6
    np.testing.assert_allclose(Jc, fd, atol=1e-5 * max(1.0, np.abs(Jc).max()))


def test_a_tight_pair_prior_puts_the_knee_axes_on_the_epicondyle_line(paired, tmp_path):
    """Squats of a simulated subject whose knee axes lie 3.6 and 4.0 deg from its epicondyle lines: with the pair
    prior tight (0.2 deg), the calibrated axes end on the markers' lines (0.3 and 0.4 deg) and the centres near their
    midpoints (0.3 and 0.4 mm, within the pair's centre prior, 5 mm: Pinocchio on the written subject); off, the
    axes end nearer the simulator's truth (3.9 and 5.1 deg from it against 4.9 and 5.5).  The knees' landmark prior
    (Priors.knee_landmark) is off in both: the pair's line alone turns the axes."""
    sim = simulate_squats(paired, frames=60, noise_mm=1.0, seed=19)
    truth_pm, truth_data = _world(paired, sim.truth, tmp_path / "truth.urdf")
    truth = {s: _against_pair(truth_pm, truth_data, f"knee_{s}", f"{s.upper()}KNE", f"{s.upper()}KNM")[0]
             for s in "lr"}
    assert min(truth.values()) > 3.0  # the truth's axes are off its pairs' lines: the prior has a pull to show
    tight = calibrate(paired, [sim.trial], Settings(priors=Priors(pair_axis=math.radians(0.2), knee_landmark=0.0)))
    off = calibrate(paired, [sim.trial], Settings(priors=Priors(pair_axis=0.0, knee_landmark=0.0)))
    assert sorted(tight.axis_pairs) == [("knee_l", "LKNE", "LKNM"), ("knee_r", "RKNE", "RKNM")]
    assert off.axis_pairs == ()
    rep = {r["coordinate"]: r for r in calibration_report(tight)["axis_pairs"]}
    pm, data = _world(tight.model, tight.params, tmp_path / "tight.urdf")
    opm, odata = _world(off.model, off.params, tmp_path / "off.urdf")
    for s in "lr":
        args = (f"knee_{s}", f"{s.upper()}KNE", f"{s.upper()}KNM")
        angle, along = _against_pair(pm, data, *args)
        assert rep[f"knee_{s}"]["angle_deg"] == pytest.approx(angle, abs=1e-6)
        assert abs(rep[f"knee_{s}"]["centre_from_midpoint_mm"]) == pytest.approx(abs(along), abs=1e-6)
        assert angle < 1.0 and abs(along) < 4.0
        # off: the axis where the motion and the axis prior put it, nearer the simulator's truth than the tight
        # prior's, which the markers' line pulls away from it
        truth_axis = _axis(truth_pm, truth_data, f"knee_{s}")
        assert abs(float(_axis(opm, odata, f"knee_{s}") @ truth_axis)) > abs(float(_axis(pm, data, f"knee_{s}")
                                                                               @ truth_axis))
    assert "axis pairs   knee_" in summary_text(tight) and "axis pairs" not in summary_text(off)
    # An axis beyond 3 SDs of its line is named, with its segment's markers a static shows elsewhere (MovedMarker,
    # kept in the fit) where there are some: here every axis, read against a 0.01 deg SD.
    from calibrate.calibration.moved import MovedMarker
    strict = replace(tight, settings=replace(tight.settings, priors=Priors(pair_axis=math.radians(0.01))),
                     moved_kept=(MovedMarker(0, "LTHI", "femur_l", 0.03, 5.0),
                                 MovedMarker(0, "LSHO", "torso", 0.04, 6.0)))
    line = next(x for x in summary_text(strict).splitlines() if x.startswith("  axis pairs"))
    assert "knee_l, knee_r beyond 3 SDs" in line or "knee_r, knee_l beyond 3 SDs" in line
    assert "LTHI sit elsewhere" in line and "LSHO" not in line
    assert "beyond" not in next(x for x in summary_text(tight).splitlines() if x.startswith("  axis pairs"))
    page = report_html(calibration_report(tight))
    assert "axes drawn along the line of the two markers" in page and f"{rep['knee_l']['angle_deg']:.1f} deg" in page


def test_a_static_alone_shows_the_medial_markers_and_their_names_place_them(human, paired):
    """A lab's medial knee markers on in the static only, their names unknown to the model (human.urdf): named as
    medial markers (hosts.medial_host), they go on the femur each knee hangs from, where the static shows them (the
    knee as wide as the simulator's subject's to 3 mm), and draw the knee axes along their pairs; a name that says
    no medial marker, or no side, places nothing."""
    from calibrate.calibration.hosts import medial_host
    from calibrate.simulation.simulate import simulate_static

    cases = {"r_mknee": "femur_r", "L.MKnee": "femur_l", "LKNM": "femur_l", "R_FME": "femur_r", "L_mankle": "tibia_l",
             "RTAM": "tibia_r", "R_elbow_med": "humerus_r", "LMEL": "humerus_l", "LKNE": None, "mknee": None,
             "r_mknee_study": "femur_r", "L_mankle_study": "tibia_l",
             # Plug-in Gait's and the CGM's medial malleoli (pyCGM2 reads LMED / RMED so) and clinical labs' spellings
             # (C3D-parser's test sessions: FMC's LKNEMED, AUC's RMed_kn / LMed_ank, RBWH's LMKN); a medial toe marker
             # is no hinge's
             "RMED": "tibia_r", "LKNEMED": "femur_l", "RMed_kn": "femur_r", "LMed_ank": "tibia_l", "LMKN": "femur_l",
             "RMed_toe": None,
             # the medial twins of the lateral spellings the aliases read (a treadmill lab's LMEE beside its LLEE)
             "LMEE": "humerus_l", "RMEK": "femur_r", "L_MedialMalleolus": "tibia_l", "LLEE": None, "RLEK": None}
    assert {n: (h[0] if (h := medial_host(human, n)) else None) for n in cases} == cases
    squats = simulate_squats(paired, frames=60, noise_mm=1.0, seed=6)
    static = simulate_static(paired, squats.truth, frames=40, noise_mm=1.0, seed=1)
    renamed = {"LKNM": "L_mknee", "RKNM": "r_mknee"}
    static_trial = replace(static.trial, labels=[renamed.get(n, n) for n in static.trial.labels])
    moving = squats.trial.select([n for n in squats.trial.labels if n not in renamed])
    cal = calibrate(human, [static_trial, moving], Settings())
    placed = {m.label: m for m in cal.new_markers}
    for name, lab in renamed.items():
        side = lab[0].lower()
        assert placed[lab].segment == f"femur_{side}" and "medial marker of knee_" in placed[lab].reason
        # where the static shows it (its residuals there), the knee as wide as the simulated subject's
        k, t = cal.model.marker_index(lab), paired.marker_index(name)
        assert np.sqrt(np.nanmean(np.sum(cal.residuals[cal.trial_frames(0), k] ** 2, axis=-1))) < 0.003
        seg, lateral = paired.segment_index(f"femur_{side}"), f"{side.upper()}KNE"
        span = cal.params.scale[seg] * np.linalg.norm(cal.params.marker[k]
                                                      - cal.params.marker[cal.model.marker_index(lateral)])
        truth = squats.truth.scale[seg] * np.linalg.norm(squats.truth.marker[t]
                                                         - squats.truth.marker[paired.marker_index(lateral)])
        assert span == pytest.approx(truth, abs=0.003)
    assert sorted(cal.axis_pairs) == [("knee_l", "LKNE", "L_mknee"), ("knee_r", "RKNE", "r_mknee")]


def test_the_priors_kept_pattern_gives_the_general_products_numbers(paired):
    """The priors' Jacobian through the layout's tangent map, from what is kept between calls (the nonzeros' product
    pattern, priors._Product, and the map's values alone, ParameterLayout.tangent_values), is the general product's
    (T given as a matrix) bit for bit at two points (the second from the kept pattern), and its Gram matrix JᵀJ."""
    sim = simulate_squats(paired, frames=3, noise_mm=1.0, seed=4)
    problem, found = _pairs(paired, sim.trial)
    assert len(found) == 2  # the pair rows, built for all pairs at once, are among them
    L, rng = problem.layout, np.random.default_rng(5)
    rows, cols = L.tangent_nonzeros()
    for _ in range(2):
        p = problem.retract_parameters(sim.truth.vector(), 0.03 * rng.normal(size=problem.n_free))
        T = problem.tangent_map(p)
        np.testing.assert_array_equal(L.tangent_values(p), T[rows, cols])
        r, J = problem.prior(p)
        r_general, J_general = problem.prior(p, T)
        np.testing.assert_array_equal(r, r_general)
        np.testing.assert_array_equal(J, J_general)
        r_gram, J_gram, G = problem.prior_gram(p)
        np.testing.assert_array_equal(r_gram, r)
        np.testing.assert_array_equal(J_gram, J)
        np.testing.assert_allclose(G, J.T @ J, rtol=1e-13, atol=1e-13 * np.abs(G).max())


def test_a_held_axis_keeps_its_centre_at_its_pairs_midpoint(paired, tmp_path):
    """A knee whose axis is held (a static's, --hold-axes) has no motion to place its centre, nor an axis to draw
    along its epicondyles: its centre is drawn to their midpoint (Priors.on_axis; held_pair_terms), three rows
    s (c - (x1 + x2) / 2) / sd in the femur's frame.  Rajagopal's static left both knee centres 100 mm from their
    epicondyles without them (docs/benchmarks.md).  Checked: which hinges get them, their values against the midpoint
    computed here, their Jacobian against differences, and a simulated static alone against the truth."""
    from calibrate.calibration.evaluate import compare_to_truth
    from calibrate.simulation.simulate import simulate_static

    sim = simulate_squats(paired, frames=3, noise_mm=1.0, seed=4)
    obs = marker_columns(paired, sim.trial)
    held = Problem(paired, obs, Settings(hold_axes=("knee_l", "knee_r")), build_kinematics(paired))
    names = [(paired.joints[j].name, paired.markers[a].name, paired.markers[b].name) for j, a, b, _ in
             held.held_pair_terms()]
    assert names == [("knee_l", "LKNE", "LKNM"), ("knee_r", "RKNE", "RKNM")] and held.pair_terms() == []
    free = Problem(paired, obs, Settings(), build_kinematics(paired))  # calibrated axes: drawn along the pair instead
    assert free.held_pair_terms() == [] and len(free.pair_terms()) == 2
    rng = np.random.default_rng(5)
    p = held.retract_parameters(sim.truth.vector(), 0.02 * rng.normal(size=held.n_free))
    r, J = held.prior(p)
    np.testing.assert_allclose(J, prior_jacobian_by_differences(held, p), atol=1e-5 * max(1.0, np.abs(J).max()))
    L, prm = held.layout, paired.unpack(p)
    for side in "lr":
        ji = paired.joint_index(f"knee_{side}")
        k1, k2 = paired.marker_index(f"{side.upper()}KNE"), paired.marker_index(f"{side.upper()}KNM")
        # the rows that reach the medial marker and the knee centre: the pair's (the on-axis row has the lateral only)
        rows = np.flatnonzero((np.abs(J[:, L.cols("marker", k2)]).sum(1) > 0)
                              & (np.abs(J[:, L.cols("centre", ji)]).sum(1) > 0))
        s = prm.scale[paired.segment_index(f"femur_{side}")]
        mid = 0.5 * (prm.marker[k1] + prm.marker[k2])
        np.testing.assert_allclose(r[rows], s * (prm.centre[ji] - mid) / Priors().on_axis, rtol=1e-9)
    # A simulated static alone (every hinge axis held): each knee centre ends within 8 mm of its pair's midpoint (the
    # truth's 5 mm from it), 6.5 and 3.7 mm, measured; with on_axis off, 32.5 and 25.7 mm, and twice as far from the
    # truth's centre (7.2 and 9.7 against 26.3 and 22.9 mm, measured).
    squats = simulate_squats(paired, frames=60, noise_mm=1.0, seed=7)
    static = simulate_static(paired, squats.truth, frames=40, noise_mm=1.0, seed=1)
    cal = calibrate(paired, static.trial, Settings())
    off = calibrate(paired, static.trial, Settings(priors=Priors(on_axis=0.0)))
    rep = calibration_report(cal)
    far = {r["joint"]: r["centre_from_midpoint_mm"] for r in rep["pair_centres"]}
    assert sorted(far) == ["knee_l", "knee_r"] and max(far.values()) < 8.0, far
    assert calibration_report(off)["pair_centres"] == []
    err, err_off = (compare_to_truth(c, static, floor=0.0).centre_error for c in (cal, off))
    assert err["knee_l"] + err["knee_r"] < 0.5 * (err_off["knee_l"] + err_off["knee_r"]), (err, err_off)
    # ... said in the summary and the HTML report
    line = next(x for x in summary_text(cal).splitlines() if x.startswith("  pair centres "))
    assert "knee_l" in line and "LKNE-LKNM's midpoint" in line and "prior SD 10 mm" in line
    assert "midpoint of the two markers straddling each joint" in report_html(rep)
