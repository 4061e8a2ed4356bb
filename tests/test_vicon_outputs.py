"""Vicon model outputs (Plug-in Gait bones, joint centres, angles, moments...) are never markers:
the C3D reader keeps them apart in Trial.model_outputs, in SI units; plugin_gait_centres reads
Plug-in Gait's own hip, knee and ankle centres from them."""

from __future__ import annotations

from pathlib import Path

import ezc3d
import numpy as np
import pytest

from calibrate.calibration.pipeline import calibrate
from calibrate.calibration.report import calibration_report, summary_text
from calibrate.io.c3d import read_c3d
from calibrate.io.trc import read_trc, write_trc
from calibrate.io.vicon import is_model_output, plugin_gait_centres
from calibrate.problem.settings import Settings
from calibrate.simulation.simulate import simulate_squats

REAL = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "real" / "pig_walk"
PLACED_BEFORE = ("HEDO", "HEDA", "HEDL", "HEDP", "LRAO", "LHNP", "RHUO", "RRAO", "RRAP", "RHNP")


def write_vicon_file(path: Path, markers: dict[str, np.ndarray], outputs: dict[str, np.ndarray],
                     groups: dict[str, list[str]], units: dict[str, str]) -> None:
    """A C3D as Nexus writes it: markers, then outputs; POINT:<group> lists and <unit> parameters."""
    labels = [*markers, *outputs]
    data = np.stack([*markers.values(), *outputs.values()], axis=1)  # (frames, points, 3)
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [100.0]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    for group, names in groups.items():
        c3d.add_parameter("POINT", group, names)
    for name, unit in units.items():
        c3d.add_parameter("POINT", name, [unit])
    c3d.add_parameter("POINT", "TYPE_GROUPS", ["ANGLES", "ANGLE", "MODELED_MARKERS", "MODELED_MARKER",
                                               "EXTRAS", "EXTRA"])
    points = np.ones((4, len(labels), data.shape[0]))
    points[:3] = data.transpose(2, 1, 0)
    c3d["data"]["points"] = points
    c3d.write(str(path))


def test_outputs_by_parameter_and_by_name_are_kept_apart_in_si_units(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    frames = 5
    markers = {name: rng.uniform(100, 900, (frames, 3)) for name in ("LASI", "RASI", "LKNE", "R.Knee")}
    outputs = {
        "LKneeAngles": rng.uniform(-40, 40, (frames, 3)),       # POINT:ANGLES, deg
        "LKneeMoment": rng.uniform(-900, 900, (frames, 3)),     # POINT:MOMENTS, N mm
        "CentreOfMass": rng.uniform(100, 900, (frames, 3)),    # POINT:MODELED_MARKERS, mm
        "Extra1": rng.uniform(1, 2, (frames, 3)),              # a group named only in TYPE_GROUPS
        "LFEO": rng.uniform(100, 900, (frames, 3)),            # in no group: a Plug-in Gait bone by name
        "LTIO": rng.uniform(100, 900, (frames, 3)),
        "LFEP": rng.uniform(100, 900, (frames, 3)),
        "RHJC": rng.uniform(100, 900, (frames, 3)),            # a joint centre by name
    }
    path = tmp_path / "nexus.c3d"
    write_vicon_file(path, markers, outputs,
                     {"ANGLES": ["LKneeAngles"], "MOMENTS": ["LKneeMoment"], "MODELED_MARKERS": ["CentreOfMass"],
                      "EXTRAS": ["Extra1"]},
                     {"ANGLE_UNITS": "deg", "MOMENT_UNITS": "Nmm", "MODELED_MARKER_UNITS": "mm",
                      "EXTRA_UNITS": "furlong"})
    trial = read_c3d(path)
    assert trial.labels == ("LASI", "RASI", "LKNE", "R.Knee")
    assert set(trial.model_outputs) == set(outputs)
    got = trial.model_outputs
    assert np.allclose(got["LKneeAngles"], np.radians(outputs["LKneeAngles"]), atol=1e-6)
    assert np.allclose(got["LKneeMoment"], outputs["LKneeMoment"] / 1000.0, atol=1e-6)
    assert np.allclose(got["CentreOfMass"], outputs["CentreOfMass"] / 1000.0, atol=1e-7)
    assert np.allclose(got["LFEO"], outputs["LFEO"] / 1000.0, atol=1e-7)
    assert np.allclose(got["Extra1"], outputs["Extra1"], atol=1e-6)  # unknown unit: file values kept
    assert trial.output_units == {"LKneeAngles": "rad", "LKneeMoment": "N m", "CentreOfMass": "m", "Extra1": "furlong",
                                  "LFEO": "m", "LTIO": "m", "LFEP": "m", "RHJC": "m"}
    assert trial.output_kinds["Extra1"] == "extra" and trial.output_kinds["LFEO"] == "point"
    centres = plugin_gait_centres(trial)
    assert set(centres) == {"knee_l", "ankle_l", "hip_l", "hip_r"}
    assert np.allclose(centres["knee_l"], outputs["LFEO"] / 1000.0, atol=1e-7)
    assert np.allclose(centres["hip_r"], outputs["RHJC"] / 1000.0, atol=1e-7)
    part = trial.frames(1, 3)  # outputs follow frame selection
    assert np.array_equal(part.model_outputs["LFEO"], got["LFEO"][1:3])


@pytest.mark.parametrize("label", ["PELO", "LFEA", "RHNP", "HEDL", "TRXO", "Sub01:LTIO", "LHJC", "RKneeJC",
                                   "CentreOfMassFloor", "LNormalisedGRF", "RAbsAnkleAngle", "LWaistPower"])
def test_plug_in_gait_output_names(label: str) -> None:
    assert is_model_output(label) is not None


@pytest.mark.parametrize("label", ["LASI", "RKNE", "LFHD", "CLAV", "RFIN", "LFE", "*115", "R.Knee", "PELVIS",
                                   "LHEE", "RTOE", "LFEOX"])
def test_markers_are_not_outputs(label: str) -> None:
    assert is_model_output(label) is None


def test_trc_columns_with_output_names_are_outputs(tmp_path: Path, human) -> None:  # noqa: ANN001
    sim = simulate_squats(human, frames=4, noise_mm=0.0, seed=0)
    trial = sim.trial.select(["LASI", "RASI", "LKNE"])
    from calibrate.io.trial import Trial
    renamed = Trial(("LASI", "RASI", "LFEO"), trial.markers, trial.rate)
    write_trc(tmp_path / "t.trc", renamed)
    back = read_trc(tmp_path / "t.trc")
    assert back.labels == ("LASI", "RASI") and np.allclose(back.model_outputs["LFEO"], trial.marker("LKNE"))


def test_calibration_ignores_outputs_and_says_so(human) -> None:  # noqa: ANN001
    """Outputs never become markers (not placed by rigidity, not left out); the summary says how many."""
    sim = simulate_squats(human, frames=30, noise_mm=0.5, seed=2)
    t = sim.trial
    from calibrate.io.trial import Trial
    trial = Trial(t.labels, t.markers, t.rate, model_outputs={"LFEO": t.marker("LKNE"), "HEDO": t.marker("LFHD")},
                  output_kinds={"LFEO": "point", "HEDO": "point"})
    cal = calibrate(human, trial, Settings(max_iterations=5))
    assert not cal.new_markers and not cal.ignored_labels and "LFEO" not in cal.model.marker_names
    assert "2 Vicon model outputs ignored" in summary_text(cal)
    report = calibration_report(cal)
    assert report["model_outputs_ignored"] == ["HEDO", "LFEO"] and report["unresolved"] == []


def test_a_model_output_the_marker_map_names_is_read_as_that_marker(human, tmp_path: Path,  # noqa: ANN001
                                                                     capsys) -> None:  # noqa: ANN001
    """A lab's marker set may carry Plug-in Gait's joint centres as markers (pyCGM2's LKJC at the knee centre); its
    marker map's line `LKNE = ["LFEO"]` is the user's word that the output is the model's marker: read back from a C3D
    file, the output becomes that marker (its trajectory to the file's precision) and leaves the ignored outputs;
    without the line it stays an output, and the calibration uses it only with the line.  A model with a marker of
    the output's own name reads it by that name."""
    from calibrate.io.c3d import write_c3d
    from calibrate.io.labels import map_labels
    from calibrate.io.trial import Trial

    sim = simulate_squats(human, frames=30, noise_mm=0.5, seed=2)
    t = sim.trial
    rest = tuple(label for label in t.labels if label != "LKNE")
    trial = Trial(rest, t.select(list(rest)).markers, t.rate,
                  model_outputs={"LFEO": t.marker("LKNE"), "HEDO": t.marker("LFHD")},
                  output_kinds={"LFEO": "point", "HEDO": "point"}, output_units={"LFEO": "m", "HEDO": "m"})
    write_c3d(tmp_path / "squats.c3d", trial)
    back = read_c3d(tmp_path / "squats.c3d")
    assert "LKNE" not in back.labels and set(back.model_outputs) == {"LFEO", "HEDO"}
    plain, _ = map_labels(back, human.marker_names)
    assert "LKNE" not in plain.labels and "LFEO" in plain.model_outputs
    mapped, mapping = map_labels(back, human.marker_names, {"LKNE": ["LFEO"]})
    assert "LKNE" in mapped.labels and set(mapped.model_outputs) == {"HEDO"}
    assert set(mapped.output_kinds) == {"HEDO"} and mapped.marker("LKNE").shape == t.marker("LKNE").shape
    assert np.allclose(mapped.marker("LKNE"), t.marker("LKNE"), atol=1e-5)  # the file's float32 millimetres
    assert dict((m.trial_label, m.note) for m in mapping)["LFEO"].endswith("read as a marker: the marker map names it")
    # a model whose own marker set names the point (pyCGM2's LKJC at the knee centre) reads it by its name alone
    own, named = map_labels(back, (*human.marker_names, "LFEO"))
    assert "LFEO" in own.labels and np.array_equal(own.marker("LFEO"), mapped.marker("LKNE"))
    assert dict((m.trial_label, (m.how, m.note)) for m in named)["LFEO"] == (
        "exact", "a model output of the file, read as a marker: the model has a marker of its name")
    assert set(own.model_outputs) == {"HEDO"}
    # `calibrate inspect TRIAL --model MODEL --markers MAP` lists it among the trial's labels, saying why
    from calibrate.cli.main import main

    (tmp_path / "map.toml").write_text('LKNE = ["LFEO"]\n')
    assert main(["inspect", str(tmp_path / "squats.c3d"), "--model", str(human.path),
                 "--markers", str(tmp_path / "map.toml")]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if line.strip().startswith("LFEO ")]
    assert len(rows) == 1 and rows[0].endswith("-> LKNE (map); a model output of the file, read as a marker: the "
                                               "marker map names it"), rows
    without = calibrate(human, back, Settings(max_iterations=5))
    used = calibrate(human, back, Settings(max_iterations=5), marker_map={"LKNE": ["LFEO"]})
    assert "LKNE" not in calibration_report(without)["marker_set"]["used"]
    assert "LKNE" in calibration_report(used)["marker_set"]["used"]
    assert "2 Vicon model outputs ignored" in summary_text(without)
    assert "1 Vicon model outputs ignored (HEDO" in summary_text(used)
    assert calibration_report(used)["model_outputs_ignored"] == ["HEDO"]


needs_real = pytest.mark.skipif(not (REAL / "walk.c3d").exists(), reason="real pig_walk trials not present")


@needs_real
@pytest.mark.parametrize("name", ["static.c3d", "walk.c3d"])
def test_real_plug_in_gait_files(name: str) -> None:
    """The pyCGM sample subject: no Plug-in Gait output is a marker, and Plug-in Gait's knee and
    ankle centres (femur and tibia origins) sit KneeWidth/2 and AnkleWidth/2 plus the marker radius
    (7 mm) from the KNE and ANK markers, the subject's widths read from the file's PROCESSING group."""
    path = REAL / name
    trial = read_c3d(path)
    assert not set(PLACED_BEFORE) & set(trial.labels)
    assert not [label for label in trial.labels if is_model_output(label)]
    assert set(PLACED_BEFORE) <= set(trial.model_outputs)
    assert {"LKneeAngles", "PELO", "LFEO"} <= set(trial.model_outputs)
    processing = ezc3d.c3d(str(path))["parameters"]["PROCESSING"]
    centres = plugin_gait_centres(trial)
    assert set(centres) == {"hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r"}
    for side, s in (("L", "l"), ("R", "r")):
        for joint, marker, width in (("knee", "KNE", "KneeWidth"), ("ankle", "ANK", "AnkleWidth")):
            want = (processing[f"{side}{width}"]["value"][0] / 2 + 7.0) / 1000.0
            dist = np.linalg.norm(centres[f"{joint}_{s}"] - trial.marker(side + marker), axis=1)
            assert np.nanmedian(np.abs(dist - want)) < 1e-4, (joint, side)
    # Hip centres: symmetric about PELO, the pelvis bone's origin.
    mid = (centres["hip_l"] + centres["hip_r"]) / 2
    assert np.nanmax(np.linalg.norm(mid - trial.model_outputs["PELO"], axis=1)) < 1e-4


def test_unlabelled_trajectories_are_never_placed(human, tmp_path):
    """Vicon's unlabelled trajectories ('*115') are left out, never placed on a segment as new
    markers even when they ride rigidly on one (here: the midpoint of the femur's LKNE and LTHI),
    and the summary says so in one line; a named unknown marker at the same place is placed."""
    from calibrate import calibrate
    from calibrate.io.trial import Trial
    from calibrate.simulation.simulate import simulate_squats

    sim = simulate_squats(human, frames=120, noise_mm=1.0, seed=4)
    k, j = sim.trial.labels.index("LKNE"), sim.trial.labels.index("LTHI")
    extra = 0.5 * (sim.trial.markers[:, k] + sim.trial.markers[:, j])
    trial = Trial(sim.trial.labels + ("*115", "LKNE2"), np.concatenate([sim.trial.markers, extra[:, None],
                                                                         extra[:, None]], axis=1), sim.trial.rate)
    cal = calibrate(human, trial)
    assert "*115" in cal.ignored_labels and "*115" not in cal.model.marker_names
    assert [(m.label, m.segment) for m in cal.new_markers] == [("LKNE2", "femur_l")]
    assert "1 unlabelled trajectories ignored (*115)" in cal.text()
    # ... and the summary's marker count keeps them apart from the labels left out (a Vicon file's 42 ghosts had read
    # as 50 trial labels left out beside its 8 real ones), in the text and in the HTML report's summary
    from calibrate.calibration.html import report_html

    assert "0 trial labels left out and 1 unlabelled trajectories ignored, " in cal.text()
    assert "0 trial labels left out and 1 unlabelled trajectories ignored, " in report_html(cal.report())


def _axes(origin: np.ndarray, toward: np.ndarray, third: np.ndarray, length) -> dict[str, np.ndarray]:
    """A segment's axes as a modelling program writes them (mm): O at `origin`, A, L and P along three orthogonal
    directions built from the lines to `toward` and `third`, each `length` (mm; a number, or one per frame) from O."""
    e1 = toward - origin
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = third - origin
    e2 -= np.sum(e2 * e1, axis=1, keepdims=True) * e1
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    e3 = np.cross(e1, e2)
    r = np.broadcast_to(np.asarray(length, dtype=float).reshape(-1, 1), (len(origin), 1))
    return {"O": origin, "A": origin + r * e1, "L": origin + r * e2, "P": origin + r * e3}


def test_segment_axes_under_a_labs_own_names_are_outputs(tmp_path: Path, human) -> None:  # noqa: ANN001
    """Segment axes a modelling program wrote among the markers under names of its own (a children's hospital's
    Pelvis_GOMO ... Pelvis_GOMP at 100 mm; a lab's LFE_MO ... LFE_MP as long as the femur in each frame; its empty
    HED_MO ... beside them) are read as model outputs, not markers; four real markers so named (noise on them), or an
    exact frame whose arms are not at right angles, stay markers.  A file of axes alone is refused in one line."""
    from calibrate.io.read import read_trial
    from calibrate.io.vicon import segment_axes

    sim = simulate_squats(human, frames=40, noise_mm=1.0, seed=3)
    mm = {lab: 1e3 * sim.trial.marker(lab) for lab in ("LASI", "RASI", "LPSI", "RPSI", "LKNE", "LANK", "LTHI")}
    markers = dict(mm)
    pelvis = _axes(mm["LASI"], mm["RASI"], mm["LPSI"], 100.0)
    femur = _axes(mm["LKNE"], mm["LANK"], mm["LTHI"], np.linalg.norm(mm["LKNE"] - mm["LASI"], axis=1))
    assert np.ptp(np.linalg.norm(femur["A"] - femur["O"], axis=1)) > 5.0  # the femur's arms change with the frame
    outputs = {**{f"Pelvis_GOM{k}": v for k, v in pelvis.items()}, **{f"LFE_M{k}": v for k, v in femur.items()},
               **{f"HED_M{k}": np.full((40, 3), np.nan) for k in "OALP"}}
    skewed = dict(pelvis, P=pelvis["P"] + 30.0 * (pelvis["A"] - pelvis["O"]) / 100.0)  # exact, not at right angles
    kept = {**{f"Thigh{k}": mm[lab] for k, lab in zip("OALP", ("LASI", "RASI", "LPSI", "RPSI"), strict=True)},
            **{f"Skew{k}": v for k, v in skewed.items()}}
    path = tmp_path / "lab.c3d"
    write_vicon_file(path, {**markers, **outputs, **kept}, {}, {}, {})
    trial = read_trial(path)
    assert set(trial.labels) == set(markers) | set(kept), trial.labels
    assert set(trial.model_outputs) == set(outputs) and trial.output_kinds["Pelvis_GOMA"] == "point"
    assert np.allclose(trial.model_outputs["LFE_MA"], 1e-3 * femur["A"])
    rng = np.random.default_rng(1)
    noisy = {k: v + rng.normal(0.0, 0.1, v.shape) for k, v in pelvis.items()}  # a camera's 0.1 mm on an exact frame
    assert segment_axes([f"X{k}" for k in noisy], np.stack(list(noisy.values()), axis=1)) == []
    alone = tmp_path / "axes.c3d"
    write_vicon_file(alone, {f"Pelvis_GOM{k}": v for k, v in pelvis.items()}, {}, {}, {})
    with pytest.raises(Exception, match="axes.c3d.*only segment axes.*export the trial with its markers"):
        read_trial(alone)


def test_plug_in_gaits_knee_marker_among_the_outputs_is_read_under_the_models_spelling(human) -> None:  # noqa: ANN001
    """A knee alignment device's static carries Plug-in Gait's knee marker as an output (LKNE, where the device puts
    it; FMC's, MH's, Sydney's statics in C3D-parser's sessions).  On models/human.urdf it is the model's LKNE by its
    name; on a model that spells the landmark otherwise (gait2392's L.Knee.Lat) it is read under that spelling too,
    the same marker, but only where no marker of the trial is read as it, and only under Plug-in Gait's own name (its
    femur origin LFEO is no marker's)."""
    from calibrate.io.labels import map_labels
    from calibrate.io.trial import Trial

    gait2392 = ("L.ASIS", "R.ASIS", "L.Knee.Lat", "R.Knee.Lat", "L.Ankle.Lat", "R.Ankle.Lat", "L.Heel", "R.Heel")
    sim = simulate_squats(human, frames=10, noise_mm=0.5, seed=2)
    t = sim.trial
    shown = ("LASI", "RASI", "RKNE", "LANK", "RANK")
    outputs = {"LKNE": t.marker("LKNE"), "RKNE": t.marker("RKNE") + 0.01, "LFEO": t.marker("LKNE") + 0.05}
    trial = Trial(shown, t.select(list(shown)).markers, t.rate, model_outputs=outputs,
                  output_kinds=dict.fromkeys(outputs, "point"), output_units=dict.fromkeys(outputs, "m"))
    ours, _ = map_labels(trial, human.marker_names)
    theirs, mapping = map_labels(trial, gait2392)
    assert np.array_equal(theirs.marker("L.Knee.Lat"), ours.marker("LKNE"))
    assert np.array_equal(theirs.marker("R.Knee.Lat"), t.marker("RKNE"))  # the trial's own knee marker, not the output
    assert set(theirs.model_outputs) == {"RKNE", "LFEO"} and "LFEO" not in theirs.labels
    assert dict((m.trial_label, m.note) for m in mapping)["LKNE"].endswith(
        "read as a marker: Plug-in Gait's name of the model's L.Knee.Lat")
    plain, _ = map_labels(trial, gait2392, aliases=False)
    assert "L.Knee.Lat" not in plain.labels and "LKNE" in plain.model_outputs
