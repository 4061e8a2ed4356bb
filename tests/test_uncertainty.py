"""The posterior SDs against the errors they claim: a small run of scripts/bench_uncertainty.py
(3 simulated subjects, 150 frames each; the benchmark runs 20 or more)."""

from __future__ import annotations

import importlib.util
import sys

import numpy as np
import pytest
from conftest import ROOT

from calibrate.simulation.simulate import simulate_squats


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_uncertainty", ROOT / "scripts" / "bench_uncertainty.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_uncertainty"] = mod
    spec.loader.exec_module(mod)
    return mod


def test_world_geometry_reproduces_the_simulator(bench, human):
    """The benchmark's lab positions (Pinocchio, from the URDF written for the parameters) are the
    simulator's noise-free markers and joint centres for the truth."""
    sim = simulate_squats(human, frames=20, noise_mm=1.0, seed=2)
    g = bench.world_geometry(sim.model, sim.truth, sim.motion)
    np.testing.assert_allclose(g["markers"], sim.clean_markers, atol=1e-9)
    np.testing.assert_allclose(g["centres"], sim.clean_centres, atol=1e-9)


def test_posterior_sds_are_calibrated(bench):
    """Over 3 subjects, the z-scores (error / reported posterior SD) of the identified parameters:
    RMS within [0.8, 1.25] and at least 90 % within 2 SD (issue 18's check).  Today: RMS 1.10 and
    92.2 % within 2 SD over these 345 z-scores (20 subjects: 0.99 and 94.2 %, docs in the script).
    Every group contributes, so the check cannot pass empty."""
    out = bench.run(3, 150)
    s = out["summary"]
    assert all(s["groups"][g]["n"] > 0 for g in ("centre", "axis", "marker", "scale")), s["groups"]
    assert s["all"]["n"] > 300
    assert 0.8 <= s["all"]["rms_z"] <= 1.25, s
    assert s["all"]["within_2sd"] >= 0.90, s
    assert s["pass"]
