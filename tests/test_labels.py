"""Tests for calibrate.io.labels: marker map files, built-in aliases, conflicts, the mapping report."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calibrate.errors import CalibrateError, TrialError
from calibrate.io.c3d import write_c3d
from calibrate.io.labels import LabelConflictWarning, alias_for, load_marker_map, map_labels
from calibrate.io.read import read_trial
from calibrate.io.trial import Trial

# Hand-written from the Plug-in Gait marker set of models/human.urdf (checked against the model below).
PIG = (
    "LASI", "LPSI", "RASI", "RPSI", "LKNE", "LTHI", "LANK", "LTIB", "LHEE", "LTOE", "RKNE", "RTHI", "RANK", "RTIB",
    "RHEE", "RTOE", "C7", "CLAV", "LSHO", "RBAK", "RSHO", "STRN", "T10", "LBHD", "LFHD", "RBHD", "RFHD", "LELB",
    "LUPA", "LFRM", "LWRA", "LWRB", "LFIN", "RELB", "RUPA", "RFRM", "RWRA", "RWRB", "RFIN",
)


def make_trial(labels: list[str] | tuple[str, ...], *, seed: int = 0, source: str | None = "walk.c3d") -> Trial:
    rng = np.random.default_rng(seed)
    markers = rng.uniform(-1.0, 1.0, size=(7, len(labels), 3))
    markers[2, 0] = np.nan
    return Trial(labels=tuple(labels), markers=markers, rate=150.0, first_frame=4, source=source)


def by_trial_label(mapping) -> dict[str, tuple[str, str, str]]:  # noqa: ANN001
    return {m.trial_label: (m.label, m.how, m.note) for m in mapping}


def test_model_has_the_plug_in_gait_labels(human) -> None:  # noqa: ANN001
    assert set(human.marker_names) == set(PIG)


# ---------------------------------------------------------------------------
# Aliases
# ---------------------------------------------------------------------------

OPENSIM = {  # gait2392 / subject01-style labels -> Plug-in Gait, or None where there is no counterpart
    "R.ASIS": "RASI",
    "L.ASIS": "LASI",
    "V.Sacral": None,  # SACR: not in our model
    "R.Thigh": "RTHI",
    "R.Thigh.Upper": None,
    "R.Knee.Lat": "RKNE",
    "R.Knee.Med": None,
    "L.Shank": "LTIB",
    "R.Ankle.Lat": "RANK",
    "R.Ankle.Med": None,
    "R.Heel": "RHEE",
    "R.Toe.Tip": "RTOE",
    "Top.Head": None,
    "Sternum": "STRN",
    "R.Acromium": "RSHO",
    "L.Shoulder": "LSHO",
    "R.Elbow.Lat": "RELB",
    "L.Elbow.Med": None,
    "R.Forearm": "RFRM",
    "R.Wrist.Lat": "RWRA",
    "R.Wrist.Med": "RWRB",
}


def test_opensim_example_labels(human) -> None:  # noqa: ANN001
    trial = make_trial(list(OPENSIM))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        relabelled, mapping = map_labels(trial, human.marker_names)
    got = by_trial_label(mapping)
    for label, want in OPENSIM.items():
        if want is None:
            assert got[label] == (label, "unknown", ""), label
        else:
            assert got[label][:2] == (want, "alias"), label
    for label, want in OPENSIM.items():
        np.testing.assert_array_equal(relabelled.marker(want or label), trial.marker(label))
    assert relabelled.rate == 150.0 and relabelled.first_frame == 4 and relabelled.source == "walk.c3d"
    assert "LKNE" in mapping.missing and "RASI" not in mapping.missing
    assert len(mapping.missing) == len(PIG) - sum(v is not None for v in OPENSIM.values())


@pytest.mark.parametrize(
    ("spelling", "want"),
    [
        ("R.ASIS", "RASI"), ("RASIS", "RASI"), ("R_ASIS", "RASI"), ("r_asis", "RASI"), ("RightASIS", "RASI"),
        ("R.ASI", "RASI"), ("ASIS_R", "RASI"), ("r-asis", "RASI"), ("R ASIS", "RASI"), ("rasi", "RASI"),
        ("L.PSIS", "LPSI"), ("LPSIS", "LPSI"), ("R.Knee", "RKNE"), ("RKNEE", "RKNE"), ("knee_l", "LKNE"),
        ("LeftKneeLateral", "LKNE"), ("L.Ankle", "LANK"), ("LHEEL", "LHEE"), ("R.MT2", "RTOE"), ("RToe", "RTOE"),
        ("Clavicle", "CLAV"), ("c7", "C7"), ("Th10", "T10"), ("R.Scapula", "RBAK"), ("L.Head.Front", "LFHD"),
        ("R_Back_Head", "RBHD"), ("L.Finger", "LFIN"), ("R.UpperArm", "RUPA"), ("Elbow_L", "LELB"),
        # the Dorn sprinter set (AddBiomechanics' Expert2): lateral epicondyle, acromion, manubrium
        ("LLEPI", "LKNE"), ("RSH", "RSHO"), ("MAN", "CLAV"),
    ],
)
def test_common_spellings(human, spelling: str, want: str) -> None:  # noqa: ANN001
    _, mapping = map_labels(make_trial([spelling]), human.marker_names)
    assert by_trial_label(mapping)[spelling][:2] == (want, "alias")


@pytest.mark.parametrize("label", ["LatKnee", "Lateral", "Radius", "Back", "*12", "RHJC", "Unlabeled 1001", "R",
                                   "LMEPI", "r_sh2", "MANX"])
def test_no_false_aliases(human, label: str) -> None:  # noqa: ANN001
    assert alias_for(label, human.marker_names) is None


def test_aliases_only_map_to_labels_the_model_has() -> None:
    assert alias_for("V.Sacral", PIG) is None
    assert alias_for("V.Sacral", [*PIG, "SACR"]) == ("SACR", 2)
    assert alias_for("R.ASIS", ["LASI"]) is None


def test_exact_labels_and_unknown_labels(human) -> None:  # noqa: ANN001
    trial = make_trial(["RASI", "LASI", "Wand1", "R.Knee.Med"])
    relabelled, mapping = map_labels(trial, human.marker_names)
    assert relabelled.labels == ("RASI", "LASI", "Wand1", "R.Knee.Med")
    assert [m.how for m in mapping] == ["exact", "exact", "unknown", "unknown"]
    assert mapping.unknown == ("Wand1", "R.Knee.Med")
    np.testing.assert_array_equal(relabelled.markers, trial.markers)


def test_aliases_off(human) -> None:  # noqa: ANN001
    _, mapping = map_labels(make_trial(["R.ASIS", "LASI"]), human.marker_names, aliases=False)
    assert [(m.label, m.how) for m in mapping] == [("R.ASIS", "unknown"), ("LASI", "exact")]


# ---------------------------------------------------------------------------
# Conflicts
# ---------------------------------------------------------------------------


def test_conflict_between_aliases_goes_by_the_alias_table(human) -> None:  # noqa: ANN001
    trial = make_trial(["R.Knee", "R.Knee.Lat"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # decided by rank: no warning
        relabelled, mapping = map_labels(trial, human.marker_names)
    assert relabelled.labels == ("R.Knee", "RKNE")
    got = by_trial_label(mapping)
    assert got["R.Knee"] == ("R.Knee", "unknown", "conflict: RKNE kept R.Knee.Lat")
    assert got["R.Knee.Lat"] == ("RKNE", "alias", "conflict: kept over R.Knee")
    np.testing.assert_array_equal(relabelled.marker("RKNE"), trial.marker("R.Knee.Lat"))
    assert mapping.warnings == ()


def test_map_beats_exact_beats_alias(tmp_path: Path, human) -> None:  # noqa: ANN001
    """The marker map is the user's word: it beats a trial label that is the model's own name (c3d.org's BTS sample28
    type1.C3D labels its computed knee centre RKNE and the epicondyle RKNE1: `RKNE = ["RKNE1"]` did nothing before,
    exact won), which then takes the first free suffix and is placed like any unknown label; an exact label beats an
    alias; the map beats an alias.  A map that exchanges two labels the file swapped (RKNE and RANK) exchanges them."""
    path = tmp_path / "map.toml"
    path.write_text('RASI = ["Pelvis1"]\nRTOE = ["R.Toe.Tip"]\n')
    marker_map = load_marker_map(path)
    trial = make_trial(["R.ASIS", "Pelvis1", "RASI", "R.Toe", "R.Toe.Tip", "RASI_2"])
    relabelled, mapping = map_labels(trial, human.marker_names, marker_map)
    got = by_trial_label(mapping)
    assert got["Pelvis1"] == ("RASI", "map", "conflict: kept over RASI, R.ASIS")
    assert got["RASI"] == ("RASI_3", "unknown", "conflict: RASI kept Pelvis1; renamed RASI_3")  # RASI_2 is taken
    assert got["R.ASIS"] == ("R.ASIS", "unknown", "conflict: RASI kept Pelvis1")
    assert got["R.Toe.Tip"] == ("RTOE", "map", "conflict: kept over R.Toe")  # the map wins over an alias
    assert got["R.Toe"] == ("R.Toe", "unknown", "conflict: RTOE kept R.Toe.Tip")
    assert relabelled.labels == ("R.ASIS", "RASI", "RASI_3", "R.Toe", "RTOE", "RASI_2")
    np.testing.assert_array_equal(relabelled.marker("RASI"), trial.marker("Pelvis1"))
    np.testing.assert_array_equal(relabelled.marker("RASI_3"), trial.marker("RASI"))
    # Without the map an exact label beats an alias.
    got = by_trial_label(map_labels(trial, human.marker_names)[1])
    assert got["RASI"][:2] == ("RASI", "exact") and got["R.ASIS"] == ("R.ASIS", "unknown", "conflict: RASI kept RASI")
    # Two labels swapped for the whole trial, exchanged by the map.
    swapped = make_trial(["RKNE", "RANK", "RTIB"])
    relabelled, mapping = map_labels(swapped, human.marker_names, {"RKNE": ["RANK"], "RANK": ["RKNE"]})
    assert relabelled.labels == ("RANK", "RKNE", "RTIB") and mapping.unknown == ()
    np.testing.assert_array_equal(relabelled.marker("RKNE"), swapped.marker("RANK"))


def test_conflict_within_the_map_goes_by_its_order(tmp_path: Path, human) -> None:  # noqa: ANN001
    path = tmp_path / "map.toml"
    path.write_text('RKNE = ["KneeB", "KneeA"]\n')
    _, mapping = map_labels(make_trial(["KneeA", "KneeB"]), human.marker_names, load_marker_map(path))
    assert by_trial_label(mapping) == {
        "KneeA": ("KneeA", "unknown", "conflict: RKNE kept KneeB"),
        "KneeB": ("RKNE", "map", "conflict: kept over KneeA"),
    }


def test_tie_keeps_the_first_and_warns(human) -> None:  # noqa: ANN001
    trial = make_trial(["R_ASIS", "R.ASIS"])
    with pytest.warns(LabelConflictWarning, match="R_ASIS, R.ASIS .*RASI"):
        relabelled, mapping = map_labels(trial, human.marker_names)
    assert relabelled.labels == ("RASI", "R.ASIS")
    assert len(mapping.warnings) == 1 and "kept R_ASIS" in mapping.warnings[0]
    np.testing.assert_array_equal(relabelled.marker("RASI"), trial.marker("R_ASIS"))


def test_prefixed_labels_match_after_the_prefix(human) -> None:  # noqa: ANN001
    trial = make_trial(["Skeleton:RASI", "Skeleton:R.Knee.Lat", "Wand:Marker1", "Other:RASI", "LASI"])
    with pytest.warns(LabelConflictWarning, match="Skeleton:RASI, Other:RASI"):
        relabelled, mapping = map_labels(trial, human.marker_names)
    assert relabelled.labels == ("RASI", "RKNE", "Wand:Marker1", "Other:RASI", "LASI")
    got = by_trial_label(mapping)
    assert got["Skeleton:RASI"][:2] == ("RASI", "exact") and "prefix Skeleton:" in got["Skeleton:RASI"][2]
    assert got["Skeleton:R.Knee.Lat"][:2] == ("RKNE", "alias")
    assert got["Other:RASI"] == ("Other:RASI", "unknown", "conflict: RASI kept Skeleton:RASI")


def test_a_whole_label_beats_a_prefixed_one(human) -> None:  # noqa: ANN001
    _, mapping = map_labels(make_trial(["Sub02:RASI", "R.ASIS"]), human.marker_names)
    assert by_trial_label(mapping)["R.ASIS"][:2] == ("RASI", "alias")


def test_a_file_of_two_subjects_is_refused_until_one_is_chosen(human, tmp_path, capsys) -> None:  # noqa: ANN001
    """A session's file holding two subjects' markers (kineticstoolkit's tennis serve of Derrick and Viktor, each
    39 Plug-in Gait labels behind its prefix): map_labels refuses it with one line naming both; of_subject keeps one
    subject's labels (prefix removed) with the unprefixed ones, its model outputs too, the data unchanged."""
    names = ["LASI", "RASI", "LPSI", "RPSI", "R.Knee.Lat"]
    labels = [f"Derrick:{n}" for n in names] + [f"Viktor:{n}" for n in names] + ["*12"]
    trial = make_trial(labels)
    trial = Trial(labels=trial.labels, markers=trial.markers, rate=trial.rate, source="serve.c3d",
                  model_outputs={"Viktor:LKneeAngles": np.ones((7, 3)), "Derrick:LKneeAngles": np.zeros((7, 3))},
                  output_kinds={"Viktor:LKneeAngles": "angle", "Derrick:LKneeAngles": "angle"},
                  output_units={"Viktor:LKneeAngles": "rad", "Derrick:LKneeAngles": "rad"})
    with pytest.raises(CalibrateError, match=r"^serve\.c3d: holds the markers of 2 subjects \(Derrick: 5 of the "
                                             r"model's, Viktor: 5 of the model's\); calibrate one at a time: "
                                             r"--subject Derrick"):
        map_labels(trial, human.marker_names)
    viktor = trial.of_subject("Viktor")
    assert viktor.labels == (*names, "*12")
    np.testing.assert_array_equal(viktor.markers, trial.markers[:, [5, 6, 7, 8, 9, 10]])
    assert list(viktor.model_outputs) == ["LKneeAngles"] and viktor.model_outputs["LKneeAngles"][0, 0] == 1.0
    assert viktor.output_kinds == {"LKneeAngles": "angle"} and viktor.output_units == {"LKneeAngles": "rad"}
    relabelled, _ = map_labels(viktor, human.marker_names)
    assert relabelled.labels == ("LASI", "RASI", "LPSI", "RPSI", "RKNE", "*12")
    with pytest.raises(TrialError, match=r"^serve\.c3d: no labels of subject 'Bob' \(its subjects: Derrick, "
                                         r"Viktor\)"):
        trial.of_subject("Bob")
    plain = make_trial(names)
    assert plain.of_subject("Viktor") is plain  # one subject, its prefix removed on reading
    # calibrate inspect names the subjects.
    from calibrate.cli import main
    from calibrate.io.trc import write_trc

    write_trc(tmp_path / "serve.trc", trial)
    assert main(["inspect", str(tmp_path / "serve.trc")]) == 0
    out = capsys.readouterr().out
    assert "  subjects: Derrick (5 labels), Viktor (5 labels): calibrate one at a time (--subject NAME)" in out
    # A second prefix matching fewer than SUBJECT_MARKERS of the model's markers is no subject (a wand, a prop).
    with pytest.warns(LabelConflictWarning, match="Derrick:LASI, Wand:LASI"):
        map_labels(make_trial([f"Derrick:{n}" for n in names] + ["Wand:LASI", "Wand:Marker1"]), human.marker_names)


# ---------------------------------------------------------------------------
# Marker map files
# ---------------------------------------------------------------------------


def test_load_marker_map(tmp_path: Path) -> None:
    path = tmp_path / "markers.toml"
    path.write_text('# lab A\nRASI = ["R.ASIS", "RASIS", "R.ASIS"]\nC7 = "Neck"\n"RKNE" = [" R Knee "]\n')
    marker_map = load_marker_map(path)
    assert marker_map == {"RASI": ["R.ASIS", "RASIS"], "C7": ["Neck"], "RKNE": ["R Knee"]}
    assert isinstance(marker_map, dict) and marker_map.source == str(path)
    assert list(marker_map) == ["RASI", "C7", "RKNE"]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("RASI = [R.ASIS]\n", "not valid TOML"),
        ("RASI = 3\n", "RASI = 3 is not a list of trial labels"),
        ("[RASI]\nx = 1\n", "RASI = a table is not a list"),
        ("RASI = [1, 2]\n", "RASI = \\[1, 2\\] is not a list"),
        ("RASI = []\n", "RASI lists no trial labels"),
        ('RASI = ["R.ASIS", " "]\n', "RASI lists an empty trial label"),
        ('RASI = ["Knee"]\nRKNE = ["Knee"]\n', "'Knee' is listed under both RASI and RKNE"),
        ('"RASI " = ["R.ASIS"]\n', "surrounding spaces"),
    ],
)
def test_bad_marker_map_files(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad_map.toml"
    path.write_text(text)
    with pytest.raises(CalibrateError, match=match) as excinfo:
        load_marker_map(path)
    message = str(excinfo.value)
    assert message.startswith(f"{path}: ") and "; " in message and "\n" not in message


def test_missing_and_directory_marker_maps(tmp_path: Path) -> None:
    for path, match in [(tmp_path / "nope.toml", "no such file"), (tmp_path, "directory")]:
        with pytest.raises(CalibrateError, match=match) as excinfo:
            load_marker_map(path)
        assert str(excinfo.value).startswith(f"{path}: ")


def test_map_entry_for_a_label_the_model_lacks(tmp_path: Path, human) -> None:  # noqa: ANN001
    path = tmp_path / "map.toml"
    path.write_text('RASI = ["R.ASIS"]\nSACR = ["V.Sacral"]\n')
    with pytest.raises(CalibrateError, match="model label 'SACR' is not in the model") as excinfo:
        map_labels(make_trial(["R.ASIS"]), human.marker_names, load_marker_map(path))
    message = str(excinfo.value)
    assert message.startswith(f"{path}: ") and "LASI" in message and "\n" not in message


def test_map_entry_listing_another_model_label(tmp_path: Path, human) -> None:  # noqa: ANN001
    """A map may give a trial label that is a model label to another model label (the left and right knee markers
    swapped for a whole session: the map's word wins); the model label it leaves is named missing."""
    path = tmp_path / "swap.toml"
    path.write_text('RKNE = ["LKNE"]\n')
    relabelled, mapping = map_labels(make_trial(["LKNE", "RASI"]), human.marker_names, load_marker_map(path))
    assert relabelled.labels == ("RKNE", "RASI") and "LKNE" in mapping.missing and "RKNE" not in mapping.missing


def test_plain_dict_map(human) -> None:  # noqa: ANN001
    relabelled, mapping = map_labels(make_trial(["hip_r", "x"]), human.marker_names, {"RASI": ["hip_r"]})
    assert relabelled.labels == ("RASI", "x")
    with pytest.raises(CalibrateError, match="^marker map: model label 'HIP'"):
        map_labels(make_trial(["hip_r"]), human.marker_names, {"HIP": ["hip_r"]})


# ---------------------------------------------------------------------------
# Report and round trip
# ---------------------------------------------------------------------------


def test_to_json_and_text(human) -> None:  # noqa: ANN001
    _, mapping = map_labels(make_trial(["R.ASIS", "LASI", "R.Knee", "R.Knee.Lat", "Wand1"]), human.marker_names)
    rows = mapping.to_json()
    assert rows[0] == {"trial_label": "R.ASIS", "label": "RASI", "how": "alias", "note": ""}
    assert [row["how"] for row in rows] == ["alias", "exact", "unknown", "alias", "unknown"]
    assert json.loads(json.dumps(rows)) == rows
    text = mapping.text()
    lines = text.splitlines()
    assert lines[0].split() == ["trial", "label", "label", "how", "note"]
    assert lines[1].split() == ["R.ASIS", "RASI", "alias"]
    assert lines[3].split()[:3] == ["R.Knee", "=", "unknown"] and "conflict: RKNE kept R.Knee.Lat" in lines[3]
    assert lines[6] == "1 exact, 0 map, 2 alias, 2 unknown"
    assert lines[7].startswith(f"model labels not in the trial ({len(PIG) - 3}): LPSI, RPSI, LKNE")


def test_round_trip_through_c3d(tmp_path: Path, human) -> None:  # noqa: ANN001
    """Vicon-style prefixed OpenSim labels written with write_c3d, read back (prefix removed) and mapped."""
    labels = ["Sub01:R.ASIS", "Sub01:L.ASIS", "Sub01:R.Knee.Lat", "Sub01:R.Toe.Tip", "Sub01:V.Sacral", "Sub01:RKNE2"]
    trial = make_trial(labels, source=None)
    path = tmp_path / "sub01.c3d"
    write_c3d(path, trial, units="mm")
    read = read_trial(path)
    assert read.labels == ("R.ASIS", "L.ASIS", "R.Knee.Lat", "R.Toe.Tip", "V.Sacral", "RKNE2")
    relabelled, mapping = map_labels(read, human.marker_names)
    assert relabelled.labels == ("RASI", "LASI", "RKNE", "RTOE", "V.Sacral", "RKNE2")
    assert [m.how for m in mapping] == ["alias"] * 4 + ["unknown"] * 2
    for old, new in zip(labels, relabelled.labels, strict=True):
        np.testing.assert_allclose(relabelled.marker(new), trial.marker(old), rtol=0, atol=1e-6, equal_nan=True)
    assert relabelled.source == str(path)


# ISB / CAST / Van Sint Jan landmark names -> the Plug-in Gait marker put on the same landmark.
ISB_NAMES = {
    "RIAS": "RASI", "L_IAS": "LASI", "R.IPS": "RPSI", "LIPS": "LPSI",
    "R_FLE": "RKNE", "LLFE": "LKNE", "RFAL": "RANK", "L_LM": "LANK", "RFCC": "RHEE", "L_CA": "LHEE",
    "RFM2": "RTOE", "L_SM": "LTOE", "RCAJ": "RSHO", "L_AC": "LSHO", "RHLE": "RELB", "L_EL": "LELB",
    "RRSP": "RWRA", "L_RS": "LWRA", "RUSP": "RWRB", "L_US": "LWRB", "RHM2": "RFIN", "L_HM2": "LFIN",
    "SJN": "CLAV", "PX": "STRN", "CV7": "C7", "TV10": "T10",
}


def test_isb_landmark_names_become_plug_in_gait_labels(human) -> None:  # noqa: ANN001
    """A trial labelled with anatomical landmark names: every one is renamed to the model's marker on
    that landmark (alias), medial landmarks with no Plug-in Gait marker stay unknown, data unchanged."""
    labels = [*ISB_NAMES, "R_FME", "L_MM", "R.EM", "LTHI"]
    trial = make_trial(labels)
    renamed, mapping = map_labels(trial, human.marker_names)
    want = [*ISB_NAMES.values(), "R_FME", "L_MM", "R.EM", "LTHI"]
    assert renamed.labels == tuple(want)
    hows = {m.trial_label: m.how for m in mapping}
    assert all(hows[name] == "alias" for name in ISB_NAMES)
    assert mapping.unknown == ("R_FME", "L_MM", "R.EM")
    np.testing.assert_array_equal(renamed.markers, trial.markers)


def test_qualisys_head_and_jugular_spellings(human) -> None:  # noqa: ANN001
    """Qualisys's sample full-body file (ezc3d's test files, Qualisys.c3d) spells the jugular notch SNJ, the head
    markers L_HDF / R_HDB and the scapula R_SCAP: the Plug-in Gait markers on those points."""
    trial = make_trial(["SNJ", "L_HDF", "R_HDF", "L_HDB", "R_HDB", "R_SCAP", "TV8"])
    renamed, mapping = map_labels(trial, human.marker_names)
    assert renamed.labels == ("CLAV", "LFHD", "RFHD", "LBHD", "RBHD", "RBAK", "TV8")
    assert mapping.unknown == ("TV8",)


def test_french_clinical_spellings(human) -> None:  # noqa: ANN001
    """A French clinical set (BTKData's Res16bits: REAS, REPS, RCL, RML, RCAL, described R.EAS, R.EPS, R.CL...):
    the iliac spines (EAS / EPS, EIAS / EIPS), the lateral femoral condyle (CL) and malleolus (ML) are Plug-in Gait's
    ASI, PSI, KNE and ANK; the medial condyle and malleolus (CM, MM) are read by their names as medial markers; a
    clavicle (RCLAV) is no condyle."""
    from calibrate.calibration.hosts import medial_host

    trial = make_trial(["REAS", "LEAS", "REIPS", "LEIPS", "RCL", "LCL", "RML", "LML", "RCAL", "RCM", "LMM", "RCLAV"])
    renamed, mapping = map_labels(trial, human.marker_names)
    assert renamed.labels == ("RASI", "LASI", "RPSI", "LPSI", "RKNE", "LKNE", "RANK", "LANK", "RHEE", "RCM", "LMM",
                              "RCLAV")
    assert mapping.unknown == ("RCM", "LMM", "RCLAV")
    assert medial_host(human, "RCM") == ("femur_r", "knee_r") and medial_host(human, "LMM") == ("tibia_l", "ankle_l")
    assert medial_host(human, "RCLAV") is None


@pytest.mark.parametrize(("labels", "want"), [
    # a leg's set: the femur's, as the alias table reads it alone
    (["LASI", "LLateralEpicondyle", "LANK", "LHEE"], ["LASI", "LKNE", "LANK", "LHEE"]),
    # kineticstoolkit's wheelchair sprint (one side, a subject prefix): the humerus's beside the acromion and the hand
    (["BodyL:AcromionL", "BodyL:LateralEpicondyleL", "BodyL:HandL", "BodyL:C7"], ["LSHO", "LELB", "LFIN", "C7"]),
    # the knee labelled otherwise, the arm marked: the elbow's
    (["RKNE", "RLateralEpicondyle", "RANK", "RSHO"], ["RKNE", "RELB", "RANK", "RSHO"]),
    # ... no arm marked: a leg's landmark still, the knee's (RKNE, the model's own label, kept over it)
    (["RKNE", "RLateralEpicondyle", "RANK", "RHEE"], ["RKNE", "RLateralEpicondyle", "RANK", "RHEE"]),
    # an upper body's trial (kineticstoolkit's racing_full): no leg marker anywhere, the arm's on one side
    (["RSHO", "RWRA", "LateralEpicondyleL", "LateralEpicondyleR"], ["RSHO", "RWRA", "LELB", "RELB"]),
])
def test_a_bare_lateral_epicondyle_is_read_by_the_trial(human, labels: list[str], want: list[str]) -> None:  # noqa: ANN001
    """'LateralEpicondyle' names no bone: the knee's where the trial shows that leg, the elbow's where it shows the
    arm and not the leg (kineticstoolkit's sprintbasket, read as the knee's, calibrated Rajagopal2016 to a torso
    scaled 0.32 with its elbow marker on the femur) or the knee's marker otherwise."""
    renamed, mapping = map_labels(make_trial(labels), human.marker_names)
    assert list(renamed.labels) == want
    assert mapping.unknown == tuple(lab for lab in want if lab in labels and lab not in human.marker_names)
    bare = [m for m in mapping if "Epicondyle" in m.trial_label and m.how == "alias"]  # its choice in the note
    assert all(f"no named bone: the {'elbow' if m.label.endswith('ELB') else 'knee'}'s" in m.note for m in bare)
    assert bare or "conflict: RKNE kept RKNE" in by_trial_label(mapping)["RLateralEpicondyle"][2]


def test_human_body_model_spellings(human) -> None:  # noqa: ANN001
    """Motek's Human Body Model (AddBiomechanics' initial_off_treadmill trial): LLEK / RLEK the knees' lateral
    epicondyles, LLEE the elbow's, LLW / LMW the wrist's radial and ulnar sides; its anterior tibia and front thigh
    markers (LATI, FLTHI) sit elsewhere than Plug-in Gait's TIB and THI and stay unknown."""
    trial = make_trial(["LLEK", "RLEK", "LLEE", "RLEE", "LLW", "LMW", "RLW", "RMW", "LATI", "FLTHI"])
    renamed, mapping = map_labels(trial, human.marker_names)
    assert renamed.labels == ("LKNE", "RKNE", "LELB", "RELB", "LWRA", "LWRB", "RWRA", "RWRB", "LATI", "FLTHI")
    assert mapping.unknown == ("LATI", "FLTHI")


def test_human_body_model_spellings_against_rajagopals_own() -> None:
    """The same trial against the Rajagopal2016 copy in ../shared/data/real, which spells the lateral femoral condyle
    LLFC, the lateral elbow LLEL and the styloids LFAradius / LFAulna: each Human Body Model label goes to the model's
    own spelling of its landmark (before, LLEK and RLEK stayed unknown there, its femurs carried no marker the trial
    showed, and the calibration's hips ended 200-300 mm from their priors); the medial condyle is no alias."""
    from calibrate.model.model import load_model

    path = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "rajagopal_walk" / "Rajagopal2016.osim"
    if not path.exists():
        pytest.skip("rajagopal_walk is not in ../shared/data/real")
    names = load_model(path).marker_names
    assert {"LLFC", "RLFC", "LLEL", "RLEL", "LFAradius", "LFAulna", "LMFC"} <= set(names)
    trial = make_trial(["LLEK", "RLEK", "LLEE", "RLEE", "LLW", "LMW", "RLW", "RMW", "LATI", "FLTHI"])
    renamed, mapping = map_labels(trial, names)
    assert renamed.labels == ("LLFC", "RLFC", "LLEL", "RLEL", "LFAradius", "LFAulna", "RFAradius", "RFAulna", "LATI",
                              "FLTHI")
    assert mapping.unknown == ("LATI", "FLTHI")
    assert alias_for("LMFC", names) is None  # the medial condyle: no spelling of the lateral knee


def test_inspect_a_trial_against_a_model(human, tmp_path, capsys) -> None:  # noqa: ANN001
    """`calibrate inspect TRIAL --model MODEL [--markers MAP]`: each label's fate before a calibration, counted, and
    the model's markers the trial lacks; --markers without --model: one line, exit 2."""
    from calibrate.cli import main
    from calibrate.io.trc import write_trc

    trc = tmp_path / "walk.trc"
    write_trc(trc, make_trial(["RASI", "L_IAS", "Thigh_R", "TV8"]))
    table = tmp_path / "map.toml"
    table.write_text('RTHI = ["Thigh_R"]\n')
    assert main(["inspect", str(trc), "--model", str(human.path), "--markers", str(table)]) == 0
    out = capsys.readouterr().out
    assert "labels against human.urdf's 39 markers: 1 exact, 1 map, 1 alias, 1 unknown" in out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("  ") and "gaps" in ln}
    assert lines["RASI"].endswith("-> RASI (exact)") and lines["L_IAS"].endswith("-> LASI (alias)")
    assert lines["Thigh_R"].endswith("-> RTHI (map)") and lines["TV8"].endswith("unknown")
    lacks = next(ln for ln in out.splitlines() if "markers the trial lacks" in ln)
    assert "(36)" in lacks and "LTHI" in lacks and "RASI" not in lacks.split(":", 1)[1]
    assert main(["inspect", str(trc), "--markers", str(table)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_inspect_says_what_a_labels_name_places(human, tmp_path, capsys) -> None:  # noqa: ANN001
    """`calibrate inspect TRIAL --model MODEL`: a lab's hip centre (R_HJC) is added at the hip's centre and tied, its
    regression's second point (R_HJC_reg) stays unknown beside it, a medial epicondyle goes on its hinge's parent; a
    label no name places stays plainly unknown."""
    from calibrate.cli import main
    from calibrate.io.trc import write_trc

    trc = tmp_path / "walk.trc"
    write_trc(trc, make_trial(["RASI", "R_HJC", "R_HJC_reg", "L_elbow_med", "TV8"]))
    assert main(["inspect", str(trc), "--model", str(human.path)]) == 0
    out = capsys.readouterr().out
    assert "4 unknown (2 of them read by their names" in out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("  ") and "gaps" in ln}
    assert lines["R_HJC"].endswith("-> hip_r's centre (by its name: added there, a joint-centre marker)")
    assert "names hip_r's centre as R_HJC does" in lines["R_HJC_reg"] and "pelvis or femur_r" in lines["R_HJC_reg"]
    assert lines["L_elbow_med"].endswith("elbow_l's medial marker by its name: on humerus_l")
    assert lines["TV8"].endswith("unknown")


def test_the_command_line_says_a_warning_in_one_line(human, tmp_path, capsys) -> None:  # noqa: ANN001
    """A label conflict met on the command line (two prefixed labels tie for RASI) is one 'warning:' line, not
    Python's file, line and source; numpy's warnings on a trial's gaps are not shown, its others are, in one line."""
    import warnings

    from calibrate.cli import main
    from calibrate.cli.main import _show_warning
    from calibrate.io.trc import write_trc

    trc = tmp_path / "walk.trc"
    write_trc(trc, make_trial(["Skeleton:RASI", "Other:RASI", "LASI"]))
    assert main(["inspect", str(trc), "--model", str(human.path)]) == 0
    err = capsys.readouterr().err
    assert err == ("warning: trial labels Skeleton:RASI, Other:RASI all match RASI equally well; kept "
                   "Skeleton:RASI, the first in the trial (a marker map can choose)\n")
    _show_warning(RuntimeWarning("All-NaN slice encountered"), RuntimeWarning, "x.py", 1)
    _show_warning(RuntimeWarning("overflow encountered in exp"), RuntimeWarning, "x.py", 1)
    assert capsys.readouterr().err == "warning: RuntimeWarning: overflow encountered in exp\n"
    assert warnings.showwarning is not _show_warning  # the command's own, restored after it


def test_model_outputs_travel_with_the_relabelled_trial() -> None:
    trial = Trial(labels=("R.ASIS",), markers=np.zeros((3, 1, 3)), rate=100.0,
                  model_outputs={"LFEO": np.ones((3, 3))}, output_kinds={"LFEO": "point"}, output_units={"LFEO": "m"})
    renamed, _ = map_labels(trial, PIG)
    assert renamed.labels == ("RASI",) and list(renamed.model_outputs) == ["LFEO"]
    np.testing.assert_array_equal(renamed.model_outputs["LFEO"], np.ones((3, 3)))


def test_an_alias_finds_the_models_own_spelling_of_the_landmark():
    """A model without Plug-in Gait's labels (Rajagopal2016's L.Knee, L.Ankle, L.Heel beside LLMAL and LCAL):
    a trial's spelling of a landmark maps to the model label that spells the same one (Camargo et al.'s
    L_Knee_Lat -> L.Knee; before, only to a model's own LKNE), the most specific spelling where several do
    (L.Ankle's 'ankle' before LLMAL's 'lmal'), the Plug-in Gait label first where the model has it; a medial
    landmark stays unknown."""
    from calibrate.io.labels import alias_for

    rajagopal = ["L.ASIS", "LASI", "L.Knee", "L.MKnee", "LLFC", "L.Ankle", "L.MAnkle", "LLMAL", "L.Heel", "LCAL",
                 "R.Knee", "C7"]
    assert alias_for("L_Knee_Lat", rajagopal) == ("L.Knee", 1)
    assert alias_for("R_Knee_Lat", rajagopal) == ("R.Knee", 1)
    assert alias_for("L_Ankle_Lat", rajagopal) == ("L.Ankle", 1)
    assert alias_for("L_Heel", rajagopal) == ("L.Heel", 1)
    assert alias_for("L_ASIS", rajagopal) == ("LASI", 1)  # the Plug-in Gait label, which this model also has
    assert alias_for("L_Knee_Med", rajagopal) is None and alias_for("L_Ankle_Med", rajagopal) is None
    assert alias_for("RKNE", rajagopal) == ("R.Knee", 0)
    assert alias_for("L_Knee_Lat", ["LKNE", "L.Knee"]) == ("LKNE", 1)
    assert alias_for("L_Toe_Lat", rajagopal) is None


def test_a_qualisys_running_sets_spellings(human) -> None:  # noqa: ANN001
    """pyomeca/pyorerun's Qualisys running trial (Running_0002.c3d) names its posterior iliac spines LBackAsis /
    RBackAsis and its lateral knee, ankle, elbow and wrist LKneeLat, LAnkleLat, LElbowLat, LWristLat / LWristMed:
    the Plug-in Gait markers on those points; its metatarsal and phalanx markers (LMT5, LMT1, LPHAL2) and clusters
    (LThighUpperC) are no Plug-in Gait marker's landmark and stay unknown."""
    labels = ["LBackAsis", "RBackAsis", "LASIS", "RKneeLat", "LAnkleLat", "RElbowLat", "LWristLat", "LWristMed",
              "LAcromium", "LMT5", "LMT1", "LPHAL2", "LThighUpperC"]
    renamed, mapping = map_labels(make_trial(labels), human.marker_names)
    assert renamed.labels == ("LPSI", "RPSI", "LASI", "RKNE", "LANK", "RELB", "LWRA", "LWRB", "LSHO", "LMT5", "LMT1",
                              "LPHAL2", "LThighUpperC")
    assert mapping.unknown == ("LMT5", "LMT1", "LPHAL2", "LThighUpperC")


def test_bts_davis_spellings(human) -> None:  # noqa: ANN001
    """BTS's Davis-protocol files (ezc3d's and kineticstoolkit's BTS sample, c3d.org's sample28) cut 'shoulder' to
    'r should' / 'l should': the shoulder markers.  Davis et al. 1991 is the conventional gait model's marker set
    (Vicon Clinical Manager's, whence Plug-in Gait's): 'r knee 1' the lateral femoral epicondyle (KNE), 'r mall' the
    lateral malleolus (ANK), 'r bar 1' and 'r bar 2' the thigh and shank wands (THI, TIB).  Its 'r met' (the fifth
    metatarsal head, not TOE's second) stays unknown.  Before, only C7, the shoulders, the ASIS and the heels were
    read, and kineticstoolkit's BTS walk could not place its legs (18 segments unresolved)."""
    labels = ["r should", "l should", "c7", "r asis", "r bar 1", "r knee 1", "r bar 2", "r mall", "r heel", "r met",
              "l knee 1", "l mall"]
    renamed, mapping = map_labels(make_trial(labels), human.marker_names)
    assert renamed.labels == ("RSHO", "LSHO", "C7", "RASI", "RTHI", "RKNE", "RTIB", "RANK", "RHEE", "r met", "LKNE",
                              "LANK")
    assert mapping.unknown == ("r met",)
    # c3d.org's sample28 also holds BTS's computed joint centres, 'r knee' and 'r ankle' (62 and 47 mm from the
    # epicondyle and the malleolus): the Davis spellings win, the centres stay unknown.
    renamed, mapping = map_labels(make_trial(["r knee", "r ankle", "r knee 1", "r mall"]), human.marker_names)
    assert renamed.labels == ("r knee", "r ankle", "RKNE", "RANK")


def test_motive_and_qualisys_animation_set_spellings(human) -> None:  # noqa: ANN001
    """OptiTrack Motive's baseline skeleton set (and Qualisys' sports set, which spells it alike) names the ASIS
    WaistLFront / WaistRFront (Motive's documentation: on the anterior iliac spine), the lateral knee, ankle and
    elbow LKneeOut, RAnkleOut, LElbowOut and the heel LHeelBack: the Plug-in Gait markers there (LThigh, a thigh
    marker, was read as LTHI before) and BackTop C7 (on the spine right below the neck).  Its WaistLBack (10 cm above
    the hip joint, not the posterior spine), LShin and HeadTop stay unknown; a side between words reads as the side
    (knee_l_lat)."""
    labels = ["WaistLFront", "WaistRFront", "WaistLBack", "LKneeOut", "RAnkleOut", "LElbowOut", "LHeelBack",
              "RHeelBack", "LShin", "LThigh", "HeadTop", "BackTop", "knee_r_lat"]
    renamed, mapping = map_labels(make_trial(labels), human.marker_names)
    assert renamed.labels == ("LASI", "RASI", "WaistLBack", "LKNE", "RANK", "LELB", "LHEE", "RHEE", "LShin", "LTHI",
                              "HeadTop", "C7", "RKNE")
    assert mapping.unknown == ("WaistLBack", "LShin", "HeadTop")


def test_cmu_waist_spellings(human) -> None:  # noqa: ANN001
    """The CMU motion-capture database's set (Vicon's animation set; mocap.cs.cmu.edu, 2605 trials) names the pelvis
    markers front and back waist: LFWT / RFWT / LBWT / RBWT.  On CMU's 01_01 they sit 239 mm apart in front, 100 mm
    behind and 217-223 mm front to back, the ASIS' and PSIS' figures (a Plug-in Gait calibration of BTKData: 245, 105,
    216-217 mm); read as them, the pelvis is marked (it was not: no hip could be placed).  Its shin, fifth metatarsal
    and back markers (LSHN, LMT5, RBAC) stay unknown, placed on their segments like any new label; OptiTrack's
    WaistLBack (10 cm above the hip, not the spine) too."""
    labels = ["LFWT", "RFWT", "LBWT", "RBWT", "LFrontWaist", "LSHN", "LMT5", "RBAC", "WaistLBack"]
    renamed, mapping = map_labels(make_trial(labels), human.marker_names)
    assert renamed.labels[:4] == ("LASI", "RASI", "LPSI", "RPSI")
    assert mapping.unknown == ("LFrontWaist", "LSHN", "LMT5", "RBAC", "WaistLBack")  # LFrontWaist: LASI taken
    renamed, _ = map_labels(make_trial(["LFrontWaist", "RBackWaist"]), human.marker_names)
    assert renamed.labels == ("LASI", "RPSI")


def test_opencap_augmented_spellings(human) -> None:  # noqa: ANN001
    """OpenCap's marker augmenter (Pose2Sim's LSTM files): its `_study` markers read as the landmark before the suffix,
    its lateral elbow and wrist sides as ELB, WRA and WRB; medial landmarks, clusters and hip centres stay unknown.  A
    file holding both a video keypoint and the augmented marker of one name (RKnee: the knee's centre; r_knee_study:
    the lateral epicondyle) keeps the augmented one as the model's, without a tie."""
    labels = ["r.ASIS_study", "L.PSIS_study", "r_knee_study", "L_ankle_study", "r_toe_study", "r_calc_study",
              "C7_study", "r_shoulder_study", "L_lelbow_study", "r_lwrist_study", "r_mwrist_study", "r_mknee_study",
              "RHJC_study", "r_thigh1_study"]
    renamed, mapping = map_labels(make_trial(labels), human.marker_names)
    assert renamed.labels == ("RASI", "LPSI", "RKNE", "LANK", "RTOE", "RHEE", "C7", "RSHO", "LELB", "RWRA", "RWRB",
                              "r_mknee_study", "RHJC_study", "r_thigh1_study")
    trial = make_trial(["RKnee", "r_knee_study", "RShoulder", "r_shoulder_study"])
    with warnings.catch_warnings():
        warnings.simplefilter("error", LabelConflictWarning)
        renamed, mapping = map_labels(trial, human.marker_names)
    assert renamed.labels == ("RKnee", "RKNE", "RShoulder", "RSHO")
    np.testing.assert_array_equal(renamed.marker("RKNE"), trial.marker("r_knee_study"))


# c3d.org's sample10 (TYPE-2.C3D, TYPE-4.C3D): the Helen Hayes set under one- and two-letter codes, each described.
HELEN_HAYES_CODES = {"H": "Sacrum", "R": "Right ASIS", "B": "Left ASIS", "RF": "Right thigh wand", "RK": "Right knee",
                     "RB": "Right shank", "RA": "Right lateral ankle", "RD": "Right great toe",
                     "LF": "Left thigh wand", "LK": "Left knee", "LB": "Left shank", "LA": "Left lateral ankle"}


def test_coded_labels_are_read_by_their_descriptions(human) -> None:  # noqa: ANN001
    """A label its own name does not match is read by the file's description of it (c3d.org's sample10: 'RK',
    "Right knee"), after every name: an exact label, a subject's prefixed one and the built-in aliases beat it; a
    description naming nothing the model has (a sacrum, a great toe) leaves the code unknown; aliases=False reads no
    description."""
    trial = replace(make_trial(list(HELEN_HAYES_CODES)), descriptions=HELEN_HAYES_CODES)
    renamed, mapping = map_labels(trial, human.marker_names)
    assert renamed.labels == ("H", "RASI", "LASI", "RTHI", "RKNE", "RTIB", "RANK", "RD", "LTHI", "LKNE", "LTIB", "LANK")
    got = by_trial_label(mapping)
    assert got["RK"] == ("RKNE", "description", "by its description 'Right knee'")
    assert mapping.unknown == ("H", "RD")
    # the same landmark by its name elsewhere in the file wins: RKNE exact, Sub:RASI after its prefix, L.Knee an alias
    trial = replace(make_trial(["RK", "RKNE", "R", "Sub:RASI", "LK", "L.Knee"]),
                    descriptions={"RK": "Right knee", "R": "Right ASIS", "LK": "Left knee"})
    with warnings.catch_warnings():
        warnings.simplefilter("error", LabelConflictWarning)
        renamed, _ = map_labels(trial, human.marker_names)
    assert renamed.labels == ("RK", "RKNE", "R", "RASI", "LK", "LKNE")
    assert map_labels(replace(make_trial(["RK"]), descriptions={"RK": "Right knee"}), human.marker_names,
                      aliases=False)[0].labels == ("RK",)


def test_descriptions_read_from_a_c3d(tmp_path: Path, human, capsys) -> None:  # noqa: ANN001
    """POINT:DESCRIPTIONS read into Trial.descriptions where they are not the label again (ezc3d writes each label
    as its own description); `calibrate inspect TRIAL --model` shows what each code became."""
    import ezc3d

    from calibrate.cli import main

    labels = [*HELEN_HAYES_CODES, "RKNE"]
    path = tmp_path / "codes.c3d"
    write_c3d(path, make_trial(labels))
    c3d = ezc3d.c3d(str(path))
    c3d["parameters"]["POINT"]["DESCRIPTIONS"]["value"] = [*HELEN_HAYES_CODES.values(), "rkne "]
    c3d.write(str(path))
    trial = read_trial(path)
    assert trial.labels == tuple(labels)
    assert dict(trial.descriptions) == HELEN_HAYES_CODES  # "rkne " is RKNE again
    assert main(["inspect", str(path), "--model", str(human.path)]) == 0
    out = capsys.readouterr().out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("  ") and "gaps" in ln}
    assert lines["RA"].endswith("-> RANK (description); by its description 'Right lateral ankle'")
    assert lines["RK"].endswith("unknown; conflict: RKNE kept RKNE  'Right knee'")  # RKNE's own label wins
    assert "1 exact, 9 description, 3 unknown" in out
    assert lines["H"].endswith("unknown  'Sacrum'")  # the file's words beside a label they do not rename
    assert main(["inspect", str(path)]) == 0  # without a model: each label with the file's words for it
    lines = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("  ") and "gaps" in ln}
    assert lines["RA"].endswith("%  'Right lateral ankle'") and lines["RKNE"].endswith("%")


def test_an_anatomical_landmark_set_of_the_ior_protocol(human) -> None:  # noqa: ANN001
    """MOtoNMS's UNIPD walks (the IOR gait protocol's landmarks: RASIS, RPSIS, RLE / RME, RLM / RMM, RCA, RGT, RHF,
    RTT): the iliac spines, the lateral epicondyle and malleolus and the calcaneus are Plug-in Gait's ASI, PSI, KNE,
    ANK and HEE; the medial epicondyle (ME, the twin of LE, which reads as KNE) and malleolus (MM) are read by their
    names as medial markers of the knee and the ankle; the other landmarks are new labels."""
    from calibrate.calibration.hosts import medial_host

    trial = make_trial(["RASIS", "LASIS", "RPSIS", "LPSIS", "RLE", "LME", "RLM", "RMM", "RCA", "RGT", "RHF", "RTT"])
    renamed, mapping = map_labels(trial, human.marker_names)
    assert renamed.labels == ("RASI", "LASI", "RPSI", "LPSI", "RKNE", "LME", "RANK", "RMM", "RHEE", "RGT", "RHF",
                              "RTT")
    assert mapping.unknown == ("LME", "RMM", "RGT", "RHF", "RTT")
    assert medial_host(human, "LME") == ("femur_l", "knee_l") and medial_host(human, "RMM") == ("tibia_r", "ankle_r")
    assert medial_host(human, "RGT") is None and medial_host(human, "RHF") is None
