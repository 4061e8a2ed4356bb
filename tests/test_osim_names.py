"""A trial's new label OpenSim cannot take as a name (BTS's Davis labels: 'r bar 1') written to a calibrated subject's
.osim as osim_name writes it ('r_bar_1'), and read back from the trials as that marker (io.labels.map_labels)."""

from __future__ import annotations

import numpy as np
import pytest

from calibrate.errors import ModelError
from calibrate.io.labels import map_labels, osim_name
from calibrate.io.osim_export import export_osim
from calibrate.io.trial import Trial
from calibrate.model.model import add_markers, load_model


def test_a_label_with_a_space_is_written_and_read_back_under_its_opensim_name(human, tmp_path):
    assert osim_name("r bar 1") == "r_bar_1" and osim_name("L.Knee/2") == "L.Knee_2" and osim_name("RKNE") == "RKNE"
    at = np.array([0.02, -0.15, 0.06])
    model = add_markers(human, {"r bar 1": ("femur_r", at)})
    path = export_osim(model, tmp_path / "subject.osim")
    text = path.read_text()
    assert '<Marker name="r_bar_1">' in text and "r bar 1" not in text
    back = load_model(path)
    k = back.marker_names.index("r_bar_1")
    assert back.markers[k].segment == "femur_r"
    assert np.allclose(back.parameters().marker[k], at, atol=1e-9)
    # The trial's own label is read as that marker (as `calibrate ik TRIAL subject.osim` reads it); others as before.
    trial = Trial(("r bar 1", "RKNE", "odd one"), np.zeros((4, 3, 3)), 100.0)
    mapped, _ = map_labels(trial, back.marker_names, None, aliases=False)
    assert mapped.labels == ("r_bar_1", "RKNE", "odd one")


def test_two_labels_opensim_would_name_alike_are_refused(human, tmp_path):
    model = add_markers(human, {"r bar": ("femur_r", np.zeros(3)), "r_bar": ("tibia_r", np.zeros(3))})
    with pytest.raises(ModelError, match="would both be named 'r_bar' in OpenSim"):
        export_osim(model, tmp_path / "subject.osim")
    assert not (tmp_path / "subject.osim").exists()
