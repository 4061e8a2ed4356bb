"""Held joint centres (Settings.hold_centres, --hold-centres): a joint the trials barely turn (a walk's lumbar joint)
cannot place its centre, and a lab may keep it where the base model has it, at the subject's scale, against the
markers of the segment it is expressed in (as OpenSim's marker placer puts a segment's frame by its markers)."""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest
from conftest import prior_jacobian_by_differences

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import summary_text
from calibrate.errors import CalibrateError
from calibrate.io.config import settings_from_dict
from calibrate.model.model import load_model, write_model
from calibrate.problem.options import Priors
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_gait, simulate_squats
from calibrate.solve.ik import marker_columns


@pytest.mark.parametrize("free", [("scale", "centre", "axis", "marker"), ("centre", "marker")])
def test_prior_jacobian_with_held_centres_matches_finite_differences(human, human_kin, free):
    """Every prior row and free column against central differences: the lumbar and neck centres held against
    their parents' markers (pelvis 4, torso 7), the right elbow's in its frame (the humerus shows two markers)."""
    sim = simulate_squats(human, frames=3, noise_mm=1.0, seed=5)
    obs = marker_columns(human, sim.trial)
    held = Settings(free=free, hold_centres=("lumbar", "neck", "elbow_r"))
    problem = Problem(human, obs, held, human_kin)
    assert [human.joints[j].name for j, _ in problem.held_centres()] == ["lumbar", "neck"]
    rng = np.random.default_rng(3)
    p = problem.retract_parameters(sim.truth.vector(), 0.02 * rng.normal(size=problem.n_free))
    r, J = problem.prior(p)
    plain = Problem(human, obs, Settings(free=free), human_kin).prior(p)[0]
    assert r.size == plain.size + 6  # two centres against their markers, three rows each
    fd = prior_jacobian_by_differences(problem, p)
    np.testing.assert_allclose(J, fd, atol=1e-5 * max(1.0, np.abs(fd).max()))
    # At the base model the held rows cost nothing; moving the pelvis's markers together with the centre neither.
    base = human.parameters()
    at_base = problem.prior(base.vector(), jacobian=False)[0]
    np.testing.assert_allclose(at_base[plain.size:], 0.0, atol=1e-12)
    shifted = base.copy()
    pelvis = [k for k, mk in enumerate(human.markers) if mk.segment == "pelvis"]
    shifted.centre[human.joint_index("lumbar")] += [0.03, -0.01, 0.02]
    shifted.marker[pelvis] += [0.03, -0.01, 0.02]
    np.testing.assert_allclose(problem.prior(shifted.vector(), jacobian=False)[0][plain.size:plain.size + 3], 0.0,
                               atol=1e-12)
    # ... while moving the centre alone costs (its offset at the pelvis's scale) / Priors.held_centre.
    alone = base.copy()
    alone.centre[human.joint_index("lumbar")] += [0.0, 0.0, 0.004]
    rows = problem.prior(alone.vector(), jacobian=False)[0][plain.size:plain.size + 3]
    s = base.scale[human.segment_index("pelvis")]
    np.testing.assert_allclose(rows, [0.0, 0.0, s * 0.004 / Priors().held_centre], rtol=1e-9)
    # The offset is held at the size of the markers' own layout, not at the pelvis's scale: the pelvis stretched
    # with its markers and the centre kept where they are in the world (their offsets divided by the stretch) costs
    # nothing, and so does the centre's offset grown with the markers' spread (OpenSim's Scale measures a segment by
    # its markers' distances).  Held at the pelvis's scale, the stretch alone cost 0.3 of the offset (up to 114
    # prior SDs here), and gait2392's walk with the back held stretched its pelvis to 1.33-1.41 against the hold.
    lumbar, i = human.joint_index("lumbar"), human.segment_index("pelvis")
    stretched = base.copy()
    stretched.scale[i] *= 1.3
    stretched.marker[pelvis] /= 1.3
    stretched.centre[lumbar] /= 1.3
    np.testing.assert_allclose(problem.prior(stretched.vector(), jacobian=False)[0][plain.size:plain.size + 3], 0.0,
                               atol=1e-9)
    spread = base.copy()
    middle = base.marker[pelvis].mean(0)
    spread.marker[pelvis] = middle + 1.1 * (base.marker[pelvis] - middle)
    spread.centre[lumbar] = middle + 1.1 * (base.centre[lumbar] - middle)
    np.testing.assert_allclose(problem.prior(spread.vector(), jacobian=False)[0][plain.size:plain.size + 3], 0.0,
                               atol=1e-9)


def _lumbar_against_pelvis_markers(model, params, path) -> np.ndarray:
    """The lumbar joint's centre minus the centroid of the pelvis's markers, in the pelvis's frame (m): the
    model written as URDF, read back and posed by Pinocchio at its neutral configuration."""
    subject = load_model(write_model(model, path, params))
    data = subject.pin.createData()
    pin.framesForwardKinematics(subject.pin, data, pin.neutral(subject.pin))
    pelvis = data.oMf[subject.pin.getFrameId("pelvis", pin.FrameType.BODY)]
    lumbar = data.oMi[subject.pin.getJointId("lumbar_flexion")].translation
    names = [mk.name for mk in subject.markers if mk.segment == "pelvis"]
    centroid = np.mean([data.oMf[subject.pin.getFrameId(n, pin.FrameType.BODY)].translation for n in names], axis=0)
    return pelvis.rotation.T @ (lumbar - centroid)


def test_a_held_lumbar_centre_keeps_the_base_models_place_against_the_pelvis_markers(human, tmp_path):
    """A simulated walk (1 mm noise) of a subject whose lumbar centre sits elsewhere against its pelvis markers than
    the base model's: held, the calibrated centre sits where the base model has it against the pelvis's markers, at
    the pelvis's calibrated scale (to 2 mm; the URDF read back by Pinocchio); left free, it follows the subject.
    The summary says which centres are held."""
    sim = simulate_gait(human, frames=400, noise_mm=1.0, seed=3)
    held = calibrate(human, sim.trial, Settings(hold_centres=("lumbar",)))
    free = calibrate(human, sim.trial, Settings())
    base = human.parameters()
    pelvis = [k for k, mk in enumerate(human.markers) if mk.segment == "pelvis"]
    lumbar = human.joint_index("lumbar")

    def against_markers(params):
        return params.scale[human.segment_index("pelvis")] * (params.centre[lumbar] - params.marker[pelvis].mean(0))

    want = held.params.scale[human.segment_index("pelvis")] * (base.centre[lumbar] - base.marker[pelvis].mean(0))
    truth = against_markers(sim.truth)
    assert np.linalg.norm(truth - want) > 0.010, (truth, want)  # the subject's lumbar is elsewhere
    got = _lumbar_against_pelvis_markers(held.model, held.params, tmp_path / "held.urdf")
    assert np.linalg.norm(got - want) < 0.002, (got, want)
    away = _lumbar_against_pelvis_markers(free.model, free.params, tmp_path / "free.urdf")
    assert np.linalg.norm(away - truth) < np.linalg.norm(away - want), (away, truth, want)
    text = summary_text(held)
    assert "centres held lumbar (the base model's offset from pelvis's 4 markers, at the subject's scale)" in text
    assert "(held: --hold-centres; the base model's offset from pelvis's 4 markers)" in text
    assert "centres held" not in summary_text(free)


def test_hold_centres_bad_input(human, tmp_path, capsys):
    """A joint the model does not have: one line naming it (the API's CalibrateError, the command line's exit 2,
    nothing written); a config's hold_centres that is not a list of names: one line."""
    from calibrate.cli.main import main
    from calibrate.io.c3d import write_c3d

    sim = simulate_squats(human, frames=40, noise_mm=1.0, seed=2)
    with pytest.raises(CalibrateError, match="hold_centres: 'spine' is not a joint of human.urdf"):
        calibrate(human, sim.trial, Settings(hold_centres=("spine",)))
    write_c3d(tmp_path / "t.c3d", sim.trial)
    code = main([str(tmp_path / "t.c3d"), str(human.path), "-o", str(tmp_path / "out.urdf"), "--hold-centres",
                 "spine"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "'spine' is not a joint" in err[0]
    assert not (tmp_path / "out.urdf").exists()
    with pytest.raises(CalibrateError, match="'hold_centres' must be a list of joint names"):
        settings_from_dict({"hold_centres": "lumbar"})
    cfg = settings_from_dict({"hold_centres": ["lumbar"], "priors": {"held_centre_mm": 2.0}})
    assert cfg.hold_centres == ("lumbar",) and cfg.priors.held_centre == pytest.approx(0.002)


def test_the_command_line_holds_and_reports_them(human, tmp_path, capsys):
    """--hold-centres lumbar: the report's settings name it; the summary's `centres held` line."""
    from calibrate.cli.main import main
    from calibrate.io.c3d import write_c3d

    sim = simulate_gait(human, frames=200, noise_mm=1.0, seed=4)
    write_c3d(tmp_path / "walk.c3d", sim.trial)
    code = main([str(tmp_path / "walk.c3d"), str(human.path), "-o", str(tmp_path / "s.urdf"), "--hold-centres",
                 "lumbar,neck"])
    assert code == 0
    out = capsys.readouterr().out
    assert "centres held lumbar (the base model's offset from pelvis's 4 markers" in out
    assert "; neck (the base model's offset from torso's 7 markers" in out
    report = json.loads((tmp_path / "walk_report.json").read_text())
    assert report["settings"]["hold_centres"] == ["lumbar", "neck"]
    assert report["settings"]["priors"]["held_centre_mm"] == pytest.approx(0.1)
    from calibrate.calibration.html import report_html

    html = report_html(report)
    assert "centres held at the base model's offset from their parent segment's markers (--hold-centres): " \
           "lumbar, neck" in html
