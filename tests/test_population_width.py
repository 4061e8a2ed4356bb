"""Where no one measured a knee's or ankle's width, the population's (Priors.population_width): each lateral marker's
distance along the hinge axis from the centre held about the base model's at the segment's scale when the gauge slides
the hinges along their axes (Problem.slide_centres), no marker and no angle moved; checked against Pinocchio on the
written models and against central differences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import markers_in_world

from calibrate.calibration.pipeline import calibrate, population_widths
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.io.measurements import lateral_distance
from calibrate.model.kinematics import build_kinematics
from calibrate.problem.options import Priors
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns

PAIRS = [("knee_l", "LKNE"), ("knee_r", "RKNE"), ("ankle_l", "LANK"), ("ankle_r", "RANK"), ("elbow_l", "LELB"),
         ("elbow_r", "RELB")]


def _prior_distance(model, params, joint: str, marker: str) -> float:
    """The base model's lateral marker distance (m) at the subject's scale of the joint's parent segment."""
    base = model.parameters()
    seg = model.segment_index(model.joints[model.joint_index(joint)].parent)
    return float(params.scale[seg]) / float(base.scale[seg]) * lateral_distance(model, base, base, joint, marker)


def test_the_population_rows_match_their_distances_and_differences_and_the_slide_moves_no_marker(human):
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), build_kinematics(human))
    joints = [j for j, _ in PAIRS]
    rng = np.random.default_rng(5)
    p = problem.retract_parameters(sim.truth.vector(), 0.03 * rng.normal(size=problem.n_free))
    r, J = problem.population_lateral_residuals(p, joints)
    # Each row: (lateral distance - the base model's at the segment's scale) / SD, the distances read independently.
    params = human.unpack(p)
    sd = problem.settings.priors.population_width
    want = [(lateral_distance(human, params, human.parameters(), j, mk) - _prior_distance(human, params, j, mk)) / sd
            for j, mk in PAIRS]
    np.testing.assert_allclose(r, want, atol=1e-9)
    fd = np.zeros_like(J)
    for k in range(problem.n_free):
        step = np.zeros(problem.n_free)
        step[k] = 1e-6
        fd[:, k] = (problem.population_lateral_residuals(problem.retract_parameters(p, step), joints)[0]
                    - problem.population_lateral_residuals(problem.retract_parameters(p, -step), joints)[0]) / 2e-6
    np.testing.assert_allclose(J, fd, atol=1e-5 * max(1.0, np.abs(J).max()))
    # Off (SD 0) or no joints named: no rows.
    off = Problem(human, marker_columns(human, sim.trial), Settings(priors=Priors(population_width=0.0)),
                  problem.kin)
    assert off.population_lateral_residuals(p, joints)[0].size == 0
    assert problem.population_lateral_residuals(p, [])[0].size == 0
    # The slide takes them in (the hinges' slides are found together, so it is their sum of squares that falls: here
    # 223 -> 36), and the model's markers stay where they were in the world.
    slid, plain = problem.slide_centres(p, joints), problem.slide_centres(p)
    after, before = (problem.population_lateral_residuals(x, joints)[0] for x in (slid, plain))
    assert after @ after < 0.5 * (before @ before), (after, before)
    Z, Q = np.zeros((1, human.nz)), np.array([[1.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(problem.kin.batch(Z, Q, slid)[0], problem.kin.batch(Z, Q, p)[0], atol=1e-12)


def test_a_hinge_a_width_places_is_not_pulled_by_its_child_markers_priors(human):
    """Where a width places a hinge (here the population's), where the base model puts the markers riding on its child
    does not move it along its axis (gauge.SLIDE_WITHOUT_MARKERS): LTIB's prior moved 30 mm along the left knee's axis
    leaves every slid centre where it was; without the width rows the same move pulls the knee along (the markers'
    priors are then all that places it)."""
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    obs = marker_columns(human, sim.trial)
    kin = build_kinematics(human)
    problem = Problem(human, obs, Settings(), kin)
    rng = np.random.default_rng(5)
    p = problem.retract_parameters(sim.truth.vector(), 0.03 * rng.normal(size=problem.n_free))
    knee = human.joint_index("knee_l")
    axis = problem.layout.axis_direction(p, human.dof_index(human.joints[knee].dofs[0]))  # in the tibia's frame
    base = human.parameters()
    k = human.marker_index("LTIB")
    assert human.markers[k].segment == "tibia_l"
    marker = base.marker.copy()
    marker[k] += 0.03 * axis
    moved = Problem(human, obs, Settings(), kin, base=replace(base, marker=marker))
    joints = [j for j, _ in PAIRS]
    centre = human.unpack(p).centre  # before any slide
    placed = [human.unpack(x.slide_centres(p, joints)).centre for x in (problem, moved)]
    np.testing.assert_allclose(placed[1], placed[0], atol=1e-12)
    assert np.abs(placed[0] - centre).max() > 1e-3  # (the slide did move the centres)
    free = [human.unpack(x.slide_centres(p)).centre for x in (problem, moved)]
    shift = float((free[1][knee] - free[0][knee]) @ (problem._urdf[human.joints[knee].urdf_joints[0]].rotation @ axis))
    assert abs(shift) > 1e-3, shift


def test_a_marker_whose_place_along_the_axis_a_width_sets_is_not_called_unreliable(human):
    """LTIB 80 mm from its prior along the left knee's axis, the one direction its posterior leaves open (the
    prior's SD there): where a width places the knee (Problem.width_placed), that place follows the width, so it is no
    trade the data leave open and LTIB is not called unreliable (its note says why); where none does, it is."""
    from calibrate.calibration.identifiability import parameter_changes

    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    problem = Problem(human, marker_columns(human, sim.trial), Settings(), build_kinematics(human))
    knee = human.joint_index("knee_l")
    dof = human.dof_index(human.joints[knee].dofs[0])
    k = human.marker_index("LTIB")
    p = problem.base.vector().copy()
    a = problem.axis_direction(p, dof)  # the knee's axis in the tibia's frame
    scale = p[problem.layout.scale(human.segment_index("tibia_l"))]
    p[problem.layout.marker(k)] += 0.08 * a / scale  # 80 mm at the segment's scale
    sd = problem.marker_sd()[k]
    prior_cov = np.eye(problem.n_free) * sd**2
    cov = prior_cov * 1e-4  # the trial places everything ...
    c = problem.layout.cols("marker", k)
    cov[np.ix_(c, c)] = sd**2 * np.outer(a, a) + 1e-4 * sd**2 * np.eye(3)  # ... but LTIB along the knee's axis
    judged = {placed: next(x for x in parameter_changes(problem, p, cov, prior_cov, placed)
                           if x.group == "marker" and x.item == "LTIB") for placed in ((), (knee,))}
    assert judged[()].unreliable and "80 mm from where its prior puts it" in judged[()].note, judged[()]
    placed = judged[(knee,)]
    assert not placed.unreliable and "along knee_l's axis its place follows where the width puts" in placed.note
    assert placed.beyond_scale == pytest.approx(80.0, abs=1e-6)


def test_which_hinges_take_the_population_width(human):
    """Knees, ankles and elbows whose lateral marker the trial shows and whose width no one gave; a measured one keeps
    its measurement; SD 0 takes none."""
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)

    def chosen(settings: Settings, trial=sim.trial) -> tuple[str, ...]:
        return population_widths(Problem(human, marker_columns(human, trial), settings, build_kinematics(human)))

    assert chosen(Settings()) == ("knee_l", "knee_r", "ankle_l", "ankle_r", "elbow_l", "elbow_r")
    assert chosen(Settings(lateral_markers=(("knee_r", "RKNE", 0.06),))) == ("knee_l", "ankle_l", "ankle_r", "elbow_l",
                                                                            "elbow_r")
    assert chosen(Settings(priors=Priors(population_width=0.0))) == ()
    hidden = sim.trial.markers.copy()
    hidden[:, sim.trial.labels.index("LANK")] = np.nan  # a lateral marker no frame shows places nothing
    assert chosen(Settings(), trial=replace(sim.trial, markers=hidden)) == ("knee_l", "knee_r", "ankle_r", "elbow_l",
                                                                              "elbow_r")


def test_a_calibration_without_widths_slides_the_knees_ankles_and_elbows_and_moves_no_marker(human, tmp_path):
    """Simulated squats, no width measured: the knees, ankles and elbows take the population's width, their lateral
    markers ending nearer the base model's distances at the segment's scale than with the prior off (their sum of
    squares: the slides are found together); every marker of the written subject, posed by Pinocchio at every frame,
    where the calibration without the prior puts it (a change of gauge: the same fit); the summary and the report say
    which and how far."""
    sim = simulate_squats(human, frames=100, noise_mm=1.0, seed=3)
    on = calibrate(human, sim.trial, Settings(outliers=0.0))
    off = calibrate(human, sim.trial, Settings(outliers=0.0, priors=Priors(population_width=0.0)))
    assert on.population_widths == tuple(j for j, _ in PAIRS) and off.population_widths == ()
    base = human.parameters()
    gap = {name: np.array([lateral_distance(human, cal.params, base, j, mk) - _prior_distance(human, cal.params, j, mk)
                           for j, mk in PAIRS]) for name, cal in (("on", on), ("off", off))}
    assert gap["on"] @ gap["on"] < gap["off"] @ gap["off"], gap
    np.testing.assert_allclose(markers_in_world(human, on.params, on.motions[0], tmp_path, "on.urdf"),
                               markers_in_world(human, off.params, off.motions[0], tmp_path, "off.urdf"), atol=1e-6)
    np.testing.assert_allclose(on.motions[0].angles, off.motions[0].angles, atol=1e-6)
    rows = calibration_report(on)["population_widths"]
    assert [(r["joint"], r["marker"]) for r in rows] == PAIRS
    for r, (j, mk) in zip(rows, PAIRS, strict=True):
        assert r["calibrated_mm"] == pytest.approx(1000 * lateral_distance(human, on.params, base, j, mk))
        assert r["prior_mm"] == pytest.approx(1000 * _prior_distance(human, on.params, j, mk))
    assert "widths       none measured: LKNE, RKNE, LANK, RANK, LELB, RELB" in summary_text(on)
    assert calibration_report(off)["population_widths"] == [] and "widths       none" not in summary_text(off)
