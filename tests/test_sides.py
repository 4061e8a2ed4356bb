"""A model marker on the other side of the body than its name says (calibrate.model.sides): the model's own
labelling slip (opensim-models' Hamner2010 puts LHJC at the right hip), named before a run fits a trial's marker
of that name there."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from calibrate.model.model import load_model
from calibrate.model.sides import named_side, side_mismatches

HUMAN = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


@pytest.mark.parametrize(("label", "side"), [
    ("LASI", "left"), ("L.ASIS", "left"), ("R_HJC", "right"), ("RHJC", "right"), ("l_knee", "left"),
    ("Left.Knee", "left"), ("ASIS.L", "left"), ("knee_r", "right"), ("R.Toe.Tip", "right"),
    ("Lumbar", None), ("Rajagopal", None), ("C7", None), ("V.Sacral", None), ("Top.Head", None), ("L", None),
    ("L.knee_r", None)])  # both sides named: none
def test_the_side_a_name_says(label, side):
    assert named_side(label) == side


def _exchanged(tmp_path: Path) -> Path:
    """human.urdf with LASI and RASI placed each where the other belongs (their origins exchanged)."""
    text = HUMAN.read_text()
    left = '<origin xyz="0.055 0.122 0.07399999999999995" rpy="0 0 0"/>'
    right = '<origin xyz="0.055 -0.122 0.07399999999999995" rpy="0 0 0"/>'
    assert text.count(left) == 1 and text.count(right) == 1
    out = tmp_path / "human_exchanged.urdf"
    out.write_text(text.replace(left, "@L@").replace(right, left).replace("@L@", right))
    return out


def test_markers_on_the_other_side_are_named_with_their_distance(tmp_path):
    assert side_mismatches(load_model(HUMAN)) == ()
    model = load_model(_exchanged(tmp_path))
    found = {x.marker: x for x in side_mismatches(model)}
    assert set(found) == {"LASI", "RASI"}
    assert found["LASI"].named == "left" and found["RASI"].named == "right"
    # The distance from the sagittal plane, read independently: the pelvis is the model's midline segment, and
    # its lateral axis (the one its paired hip centres differ along) carries the marker's offset.
    pm = model.pin
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, model.pin_configuration(np.zeros(3), [0, 0, 0, 1], np.zeros(model.n_dofs)))
    pelvis = data.oMf[pm.getFrameId("pelvis", pin.FrameType.BODY)]
    for name in ("LASI", "RASI"):
        local = pelvis.actInv(data.oMf[pm.getFrameId(name)].translation)
        assert found[name].distance == pytest.approx(abs(local[1]), abs=1e-3)
        assert "though its name says" in found[name].text()


def test_inspect_lists_them(tmp_path):
    path = _exchanged(tmp_path)
    out = subprocess.run([sys.executable, "-m", "calibrate.cli", "inspect", str(path)], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    lines = [ln.strip() for ln in out.stdout.splitlines()]
    at = next(i for i, ln in enumerate(lines) if ln.startswith("markers on the other side"))
    assert {lines[at + 1].split()[0], lines[at + 2].split()[0]} == {"LASI", "RASI"}
    plain = subprocess.run([sys.executable, "-m", "calibrate.cli", "inspect", str(HUMAN)], capture_output=True,
                           text=True, timeout=120)
    assert "other side" not in plain.stdout


def test_a_run_whose_trial_carries_them_warns(tmp_path, capsys):
    """The trial carries LASI and RASI: the run says, in one line on stderr, that the model puts them on the other
    side (and still runs: the lab may have meant it)."""
    from calibrate.cli import main
    from calibrate.simulation.simulate import simulate_squats, write_simulation

    write_simulation(simulate_squats(load_model(HUMAN), frames=40, noise_mm=1.0, seed=5), tmp_path / "sim")
    code = main([str(tmp_path / "sim" / "trial.c3d"), str(_exchanged(tmp_path)), "-o", str(tmp_path / "s.urdf"),
                 "-q"])
    err = capsys.readouterr().err
    assert code in (0, 1) and (tmp_path / "s.urdf").exists()
    warned = [ln for ln in err.splitlines() if "though its name says" in ln]
    assert len(warned) == 1 and warned[0].startswith("warning: human_exchanged.urdf:")
    assert "LASI (on pelvis)" in warned[0] and "RASI (on pelvis)" in warned[0]
