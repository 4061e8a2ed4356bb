"""A held hinge's lateral marker on its axis (Priors.on_axis): where no motion places a knee's, ankle's or elbow's
axis (a static alone, a joint the trials do not show moving), Plug-in Gait's KNE, ANK and ELB are drawn onto the
held axis line through the centre, as the epicondyle or malleolus they sit over is.  The rows against the
geometry read back through Pinocchio, and their Jacobian against finite differences."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
from conftest import prior_jacobian_by_differences

from calibrate.model.model import write_model
from calibrate.problem.options import Priors
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns

HELD = ("knee_l", "ankle_r", "elbow_l")


def _across_axis(urdf, joint: str, marker: str) -> np.ndarray:
    """The marker's offset from the hinge's centre across its axis (m, world) at the neutral pose, from the URDF
    through Pinocchio alone (the axis: the joint's column of its world Jacobian)."""
    model = pin.buildModelFromUrdf(str(urdf))
    data = model.createData()
    q = pin.neutral(model)
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    jid = model.getJointId(joint)
    axis = pin.getJointJacobian(model, data, jid, pin.ReferenceFrame.WORLD)[3:, model.joints[jid].idx_v]
    axis = axis / np.linalg.norm(axis)
    x = data.oMf[model.getFrameId(marker)].translation - data.oMi[jid].translation
    return x - axis * float(axis @ x)


def test_held_hinges_lateral_markers_rows_and_jacobian(human, human_kin, tmp_path):
    """Three hinges held: their lateral markers' rows are the offset across the axis / SD (at the segment's scale),
    as Pinocchio reads the written geometry; the Jacobian matches central differences; calibrated axes (the
    others) and priors.on_axis = 0 give no rows."""
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    obs = marker_columns(human, sim.trial)
    problem = Problem(human, obs, Settings(hold_axes=HELD), human_kin)
    terms = [(human.joints[j].name, human.markers[k].name) for j, k, _ in problem.on_axis_terms()]
    assert terms == [("knee_l", "LKNE"), ("ankle_r", "RANK"), ("elbow_l", "LELB")]
    off = Problem(human, obs, Settings(hold_axes=HELD, priors=replace(Priors(), on_axis=0.0)), human_kin)
    assert off.on_axis_terms() == []
    free = Problem(human, obs, Settings(), human_kin)
    assert free.on_axis_terms() == []  # every axis calibrated: no rows
    rng = np.random.default_rng(4)
    p = problem.retract_parameters(sim.truth.vector(), 0.02 * rng.normal(size=problem.n_free))
    r, J = problem.prior(p)
    plain = off.prior(p)[0]
    assert r.size == plain.size + 9
    np.testing.assert_allclose(r[:plain.size], plain, atol=1e-12)
    # The rows against the geometry written as a URDF and read by Pinocchio (segment frames parallel at neutral).
    write_model(human, tmp_path / "s.urdf", human.unpack(p))
    sd = Priors().on_axis
    for k, (joint, marker) in enumerate(terms):
        across = _across_axis(tmp_path / "s.urdf", joint, marker)
        np.testing.assert_allclose(np.linalg.norm(r[plain.size + 3 * k:plain.size + 3 * k + 3]),
                                   np.linalg.norm(across) / sd, rtol=1e-6)
    fd = prior_jacobian_by_differences(problem, p)
    np.testing.assert_allclose(J, fd, atol=1e-5 * max(1.0, np.abs(fd).max()))
