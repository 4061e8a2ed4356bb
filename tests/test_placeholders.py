"""Placeholder markers: a base model that puts several markers of one segment at one place (AddBiomechanics' and
its Lai-Uhlrich 2022 model put each thigh and shank cluster at one point, for OpenSim's marker placer to move) says
nothing of where the subject's are; held there by the marker prior, they dragged the segment's scale and frame."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pinocchio as pin

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.model.model import load_model, write_model
from calibrate.problem.options import Priors
from calibrate.problem.priors import placeholder_markers
from calibrate.problem.settings import Settings
from calibrate.simulation import simulate_squats

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"
TRUE_CLUSTER = [(0.06, 0.07, -0.12), (0.07, 0.03, -0.18), (0.02, 0.09, -0.21)]  # on femur_l, m
PLACEHOLDER = (0.08, 0.06, -0.32)  # where the base model puts all three (as AddBiomechanics' models do, near the knee)


def _with_cluster(points: list[tuple[float, float, float]]) -> str:
    """models/human.urdf with three cluster markers LTH1-3 on femur_l at `points`."""
    extra = "".join(
        f'  <link name="LTH{i}"><visual><geometry><sphere radius="0.007"/></geometry></visual></link>\n'
        f'  <joint name="LTH{i}_marker" type="fixed"><parent link="femur_l"/><child link="LTH{i}"/>'
        f'<origin xyz="{x} {y} {z}" rpy="0 0 0"/></joint>\n' for i, (x, y, z) in enumerate(points, 1))
    return HUMAN.read_text().replace("</robot>", extra + "</robot>")


def _knee_error(cal, folder: Path, truth: np.ndarray) -> float:
    """Median distance (m) of the calibrated subject's knee_l centre, posed by Pinocchio at the solved
    coordinates, from the simulator's true centre, over every 10th frame."""
    subject = load_model(write_model(cal.model, folder / "subject.urdf", cal.params))
    j = [x.name for x in subject.joints].index("knee_l")
    data, jid = subject.pin.createData(), subject.pin.getJointId(subject.joints[j].urdf_joints[0])
    m, err = cal.motion, []
    for f in range(0, m.n_frames, 10):
        q = subject.pin_configuration(m.root_translation[f], m.root_quaternion[f], m.angles[f])
        pin.forwardKinematics(subject.pin, data, q)
        err.append(np.linalg.norm(data.oMi[jid].translation - truth[f, j]))
    return float(np.median(err))


def test_placeholder_markers_are_placed_by_the_data_and_do_not_size_their_segment():
    """The subject carries a thigh cluster where the simulator puts it; the base model has the three markers at one
    point 110-200 mm away.  Found as placeholders, held by a 250 mm prior, they leave the femur's scale to its
    joint centres and anatomical markers: the scale within 1 % of the simulated subject's and the knee centre within
    3 mm of the truth in the lab (2.8 since the simulator keeps LKNE by the knee's axis), nothing called unreliable.
    Held by the marker prior as before (20 mm), the same trial shrank the femur to 0.79 (truth 0.95) and put the
    knee centre 60 mm from the scaled base model's."""
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        (folder / "true.urdf").write_text(_with_cluster(TRUE_CLUSTER))
        (folder / "base.urdf").write_text(_with_cluster([PLACEHOLDER] * 3))
        truth, base = load_model(folder / "true.urdf"), load_model(folder / "base.urdf")
        assert [base.markers[k].name for k in placeholder_markers(base, base.parameters())] == ["LTH1", "LTH2", "LTH3"]
        assert placeholder_markers(truth, truth.parameters()) == ()
        sim = simulate_squats(truth, frames=150, noise_mm=1.0, seed=3)
        femur = base.segment_index("femur_l")
        true_scale = sim.truth.scale[femur]

        cal = calibrate(base, sim.trial, Settings())
        assert abs(cal.params.scale[femur] / true_scale - 1) < 0.01
        assert _knee_error(cal, folder, sim.clean_centres) < 0.003
        assert not [c.name for c in cal.changes if c.unreliable]
        report = calibration_report(cal)
        assert report["placeholder_markers"] == ["LTH1", "LTH2", "LTH3"]
        assert report["settings"]["priors"]["placeholder_mm"] == 250.0
        assert any(line.startswith("  placeholders LTH1, LTH2, LTH3: the base model puts each at one place")
                   for line in summary_text(cal).splitlines())
        # The cluster's places come from the data: the distances between its markers within 2 mm of the simulated
        # subject's (its scale times its offsets; a frame-free check: the femur's frame is the markers' gauge).
        k = [base.marker_index(f"LTH{i}") for i in (1, 2, 3)]
        placed = cal.params.scale[femur] * cal.params.marker[k]
        true = true_scale * sim.truth.marker[k]
        for a, b in ((0, 1), (0, 2), (1, 2)):
            assert abs(np.linalg.norm(placed[a] - placed[b]) - np.linalg.norm(true[a] - true[b])) < 0.002

        held = calibrate(base, sim.trial, Settings(priors=Priors(placeholder=Priors().marker)))
        assert held.params.scale[femur] / true_scale < 0.9  # the old behaviour, for contrast
        knee = next(c for c in held.changes if c.group == "centre" and c.item == "knee_l")
        assert knee.beyond_scale > 40.0  # (59 mm; along its axis the knee's width places it: not `unreliable` there)


def test_inspect_lists_placeholder_markers_and_a_bad_prior_is_one_line(tmp_path, capsys):
    """`calibrate inspect MODEL` names the placeholders before any trial; a placeholder prior that is not a positive
    SD is refused with its name."""
    import pytest

    from calibrate.cli import main
    from calibrate.errors import CalibrateError
    from calibrate.io.config import settings_from_dict

    (tmp_path / "base.urdf").write_text(_with_cluster([PLACEHOLDER] * 3))
    assert main(["inspect", str(tmp_path / "base.urdf")]) == 0
    out = capsys.readouterr().out
    assert "placeholder markers (within 1 mm of another marker of their segment" in out
    assert "\n    LTH1, LTH2, LTH3\n" in out
    assert main(["inspect", str(HUMAN)]) == 0
    assert "placeholder markers" not in capsys.readouterr().out
    assert settings_from_dict({"priors": {"placeholder_mm": 100}}).priors.placeholder == pytest.approx(0.1)
    with pytest.raises(CalibrateError, match="priors.placeholder: must be a positive standard deviation"):
        settings_from_dict({"priors": {"placeholder_mm": 0}})
