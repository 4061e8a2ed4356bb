"""A knee or ankle the gauge cannot slide along its axis (its child segment held: a trial without foot markers locks the
ankle and holds the talus) keeps its lateral marker at the measured width's distance from its centre, or the
population's, by a row of the solve's priors (Problem.unslid_width_terms): the rows against distances read
independently and central differences, and calibrations without foot markers against the simulator's truth, the
fit read back through Pinocchio."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import markers_in_world, prior_jacobian_by_differences

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report
from calibrate.io.measurements import lateral_distance
from calibrate.model.kinematics import build_kinematics
from calibrate.problem.options import Priors
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns

ANKLES = [("ankle_l", "LANK"), ("ankle_r", "RANK")]
FEET = ("talus_l", "calcn_l", "talus_r", "calcn_r")


def _without_feet(trial):
    """The trial without its heel and toe markers (a lower-limb set without feet): nothing poses the tali."""
    keep = [i for i, label in enumerate(trial.labels) if label[1:] not in ("HEE", "TOE")]
    return replace(trial, labels=[trial.labels[i] for i in keep], markers=trial.markers[:, keep])


def _prior_distance(model, params, joint: str, marker: str) -> float:
    """The base model's lateral marker distance (m) at the subject's scale of the joint's parent segment."""
    base = model.parameters()
    seg = model.segment_index(model.joints[model.joint_index(joint)].parent)
    return float(params.scale[seg]) / float(base.scale[seg]) * lateral_distance(model, base, base, joint, marker)


def test_the_rows_match_their_distances_and_central_differences(human):
    """The feet held, as the pipeline holds them without foot markers: each ankle takes one prior row, (lateral
    distance - the population's at the tibia's scale) / SD, or (- the measured one) / Priors.width where the lab gave
    the width; the knees, which the slide moves, take none; the prior's Jacobian with them equals central
    differences."""
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    trial = _without_feet(sim.trial)
    held = Settings(hold_segments=FEET, lock=(("ankle_l", 0.0), ("ankle_r", 0.0), ("subtalar_l", 0.0),
                                              ("subtalar_r", 0.0)))
    kin = build_kinematics(human)
    problem = Problem(human, marker_columns(human, trial), held, kin)
    terms = problem.unslid_width_terms()
    assert [human.joints[t[0]].name for t in terms] == ["ankle_l", "ankle_r"]
    rng = np.random.default_rng(5)
    p = problem.retract_parameters(sim.truth.vector(), 0.03 * rng.normal(size=problem.n_free))
    params = human.unpack(p)
    sd = held.priors.population_width
    want = sorted((lateral_distance(human, params, human.parameters(), j, mk) - _prior_distance(human, params, j, mk))
                  / sd for j, mk in ANKLES)
    off = Problem(human, marker_columns(human, trial), replace(held, priors=Priors(population_width=0.0)), kin)
    assert off.unslid_width_terms() == []
    r_on, r_off = problem.prior(p, jacobian=False)[0], off.prior(p, jacobian=False)[0]
    assert r_on.size == r_off.size + 2
    extra = sorted(set(r_on.tolist()) - set(r_off.tolist()))
    np.testing.assert_allclose(extra, want, atol=1e-9)
    # A measured width instead: its row is (distance - measured) / Priors.width.
    measured = replace(held, lateral_markers=(("ankle_r", "RANK", 0.045),))
    mp = Problem(human, marker_columns(human, trial), measured, kin)
    rows = {human.joints[t[0]].name: t for t in mp.unslid_width_terms()}
    assert rows["ankle_r"][4:] == (0.045, 0.0, measured.priors.width) and rows["ankle_l"][5] > 0
    got = sorted(set(mp.prior(p, jacobian=False)[0].tolist()) - set(r_off.tolist()))
    left = (lateral_distance(human, params, human.parameters(), "ankle_l", "LANK")
            - _prior_distance(human, params, "ankle_l", "LANK")) / sd
    right = (lateral_distance(human, params, human.parameters(), "ankle_r", "RANK") - 0.045) / measured.priors.width
    np.testing.assert_allclose(got, sorted([left, right]), atol=1e-9)
    for pr in (problem, mp):
        r, J = pr.prior(p)
        fd = prior_jacobian_by_differences(pr, p)
        np.testing.assert_allclose(J, fd, atol=1e-5 * max(1.0, np.abs(J).max()))


def test_a_trial_without_foot_markers_places_its_ankles_by_the_measured_width(human, tmp_path):
    """Simulated squats without heel and toe markers, the lab's caliper widths written with the trial: the ankles
    locked, their centres within 2 mm of the truth's along the axis from the malleolus markers (the caliper's error is
    2 mm SD on the width); with no width used and the population's off, the one prior left on the centre puts an
    ankle 10 mm off.  The fit is the same (every marker the trial shows, on the written subjects posed by Pinocchio,
    within 0.4 mm: 0.1 before the knees' landmark prior), and without the measurement the report lists the ankles
    among the population's widths."""
    sim = simulate_squats(human, frames=100, noise_mm=1.0, seed=3, measured=True)
    trial = _without_feet(sim.trial)
    base = human.parameters()
    runs = {name: calibrate(human, t, Settings(outliers=0.0, priors=pr)) for name, t, pr in (
        ("measured", trial, Priors()), ("population", replace(trial, measurements=None), Priors()),
        ("none", replace(trial, measurements=None), Priors(population_width=0.0)))}
    err = {name: np.array([lateral_distance(human, cal.params, base, j, mk) - lateral_distance(human, sim.truth, base,
                                                                                                 j, mk)
                           for j, mk in ANKLES]) for name, cal in runs.items()}
    assert {"ankle_l", "ankle_r"} <= set(runs["measured"].locked)
    assert np.abs(err["measured"]).max() < 0.002, err
    assert np.abs(err["none"]).max() > 0.005, err
    # (the slid hinges first, then those the solve placed)
    assert runs["population"].population_widths == ("knee_l", "knee_r", "elbow_l", "elbow_r", "ankle_l", "ankle_r")
    rows = {r["joint"]: r for r in calibration_report(runs["population"])["population_widths"]}
    for j, mk in ANKLES:
        assert rows[j]["calibrated_mm"] == pytest.approx(
            1000 * lateral_distance(human, runs["population"].params, base, j, mk))
        assert rows[j]["prior_sds"] < 1.0
    seen = [k for k, name in enumerate(human.marker_names) if name in trial.labels]  # (the feet's move with the ankles)
    np.testing.assert_allclose(
        markers_in_world(human, runs["measured"].params, runs["measured"].motions[0], tmp_path, "m.urdf")[:, seen],
        markers_in_world(human, runs["none"].params, runs["none"].motions[0], tmp_path, "n.urdf")[:, seen], atol=4e-4)
