"""A Plug-in Gait lateral marker (KNE, ANK, ELB) against its hinge centre: the report's `lateral_sides` and the
summary's `implausible` line for one that ends medial of the centre (calibrate.calibration.report.lateral_sides), or,
held by the population's width, far from it (calibrate.calibration.report.POPULATION_FAR)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import POPULATION_FAR, calibration_report, implausible_flags, lateral_sides
from calibrate.io.trial import Trial
from calibrate.model.hinges import hinge_lines_world
from calibrate.problem.options import Priors
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats


def test_lateral_distances_against_pinocchio(human):
    """The true subject's lateral distances as lateral_sides reads them equal the markers' distances from the hinge
    centres along the axes in the world, by Pinocchio's kinematics of the written model, in every frame."""
    sim = simulate_squats(human, frames=20, noise_mm=0.0, seed=4)
    sides = lateral_sides(SimpleNamespace(model=human, base_model=None, params=sim.truth, unused_markers=()))
    assert set(sides) == {f"{j}_{s}" for j in ("knee", "ankle", "elbow") for s in "lr"}
    lines = hinge_lines_world(human, sim.truth, sim.motion)
    for joint, v in sides.items():
        centre, axis = lines[joint]
        marker = sim.clean_markers[:, human.marker_index(v["marker"])]
        along = np.abs(np.einsum("fi,fi->f", marker - centre, axis))  # the truth's markers are lateral
        np.testing.assert_allclose(v["lateral_mm"], 1000 * along, atol=1e-6)
        assert not v["medial"] and v["lateral_mm"] > 15.0


def test_a_lateral_marker_across_its_joint_is_flagged(human):
    """LKNE's positions mirrored across the knee (through the true centre, normal to the true axis: the medial
    epicondyle labelled as the lateral one), and LANK's across the ankle.  By default no width is measured, so the
    population's (Priors.population_width) holds each lateral marker about the base model's distance from its centre:
    the mirrored one ends POPULATION_FAR SDs or more from it and is flagged (knee 3.1, ankle 3.0 SDs; the pull of the
    mirrored knee carries the ankle below 3.6 SDs off, flagged too), the true labels' within 0.8.  With that prior off,
    each ends medial of the calibrated centre and is flagged so (knee -36, ankle -20 mm), the ankle's line naming the
    subtalar it trades with across the markerless talus."""
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=2)
    clean = calibrate(human, sim.trial)
    assert not any(v["medial"] for v in lateral_sides(clean).values())
    assert max(r["prior_sds"] for r in calibration_report(clean)["population_widths"]) < 1.5
    assert not any("medial of the centre" in f or "population's width" in f for f in implausible_flags(clean))

    lines = hinge_lines_world(human, sim.truth, sim.motion)
    off = Settings(priors=Priors(population_width=0.0))
    for joint, marker in (("knee_l", "LKNE"), ("ankle_l", "LANK")):
        centre, axis = lines[joint]
        k = sim.trial.labels.index(marker)
        X = sim.trial.markers.copy()
        X[:, k] -= 2.0 * np.einsum("fi,fi->f", X[:, k] - centre, axis)[:, None] * axis
        trial = Trial(sim.trial.labels, X, sim.trial.rate, 0, None)
        cal = calibrate(human, trial)
        rows = {r["joint"]: r for r in calibration_report(cal)["population_widths"]}
        assert rows[joint]["far"] and rows[joint]["prior_sds"] > POPULATION_FAR, rows[joint]
        flags = [f for f in implausible_flags(cal) if "population's width" in f]
        assert any(f.startswith(f"{joint}: {marker} ends") for f in flags), flags
        assert {f.split(":")[0] for f in flags} == {j for j, r in rows.items() if r["far"]}
        cal = calibrate(human, trial, off)
        sides = lateral_sides(cal)
        assert sides[joint]["medial"] and sides[joint]["lateral_mm"] < -10.0, sides[joint]
        assert not any(v["medial"] for j, v in sides.items() if j != joint)
        flags = [f for f in implausible_flags(cal) if "medial of the centre" in f]
        assert len(flags) == 1 and flags[0].startswith(f"{joint}: {marker} ends")
        assert ("--lock subtalar_l" in flags[0]) == (joint == "ankle_l")  # the talus carries no marker
        assert calibration_report(cal)["lateral_sides"][joint] == sides[joint]
