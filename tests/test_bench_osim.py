"""scripts/bench_osim.py's pieces that need neither OpenSim nor nimblephysics: the .osim it hands nimble."""

import sys
from pathlib import Path

import numpy as np
import pytest

from calibrate.model.model import load_model

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "data" / "real"
sys.path.insert(0, str(ROOT / "scripts"))
import bench_osim  # noqa: E402

CASES = {"gait2392": (REAL / "gait2392" / "gait2392.osim", REAL / "gait2392" / "gait2392_Scale_MarkerSet.xml"),
         "rajagopal": (REAL / "rajagopal_walk" / "Rajagopal2016.osim",
                       REAL / "rajagopal_walk" / "markerset_walk_preScale.xml")}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_marker_set_written_into_the_osim_is_the_model_the_scale_tool_would_read(tmp_path, case):
    """nimble reads one .osim, so bench_osim writes the marker set file's markers into the generic model (OpenSim 3
    <body> markers as OpenSim 4 socket_parent_frame ones, replacing those of the same name): read back by
    calibrate's OpenSim reader, that file must carry exactly the markers of the model read with the marker set
    file beside it (which test_osim_import checks against OpenSim itself)."""
    osim, marker_set = CASES[case]
    if not osim.exists():
        pytest.skip(f"{osim} not found (the real trials)")
    written = bench_osim.osim_with_markers({"osim": str(osim), "marker_set": str(marker_set)},
                                           tmp_path / f"{case}_with_markers.osim")
    merged, reference = load_model(written), load_model(osim, marker_set)
    assert sorted(merged.marker_names) == sorted(reference.marker_names)
    for name in reference.marker_names:
        a, b = merged.markers[merged.marker_index(name)], reference.markers[reference.marker_index(name)]
        assert a.segment == b.segment, name
        np.testing.assert_allclose(a.offset, b.offset, atol=1e-12, err_msg=name)
    # The generic model's kinematics are untouched: the same joints, axes and centres.
    np.testing.assert_allclose(merged.parameters().centre, reference.parameters().centre, atol=1e-12)
    np.testing.assert_allclose(merged.parameters().axis, reference.parameters().axis, atol=1e-12)


def test_the_running_pipelines_need_an_opensim_models_checkout(tmp_path):
    """The running cases read an opensim-models checkout (not in ../shared): asked for without one, or with a folder
    lacking their files, bench_osim says which file it did not find and exits 2 before running anything."""
    import subprocess

    script = str(ROOT / "scripts" / "bench_osim.py")
    for args in (["--only", "hamner"], ["--opensim-models", str(tmp_path)]):
        proc = subprocess.run([sys.executable, script, *args, "--no-nimble"], capture_output=True, text=True,
                              timeout=120)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "not found" in lines[0] and "Pipelines" in lines[0] and "opensim-models" in lines[0]


def test_bench_dynamics_needs_the_hamner_pipeline_with_its_dynamics_files(tmp_path):
    """bench_dynamics reads Pipelines/Hamner of an opensim-models checkout, its ground forces and RRA setup too:
    without a checkout, or with one lacking the RRA setup, it names the file it did not find, exits 2 and runs
    nothing."""
    import subprocess

    hamner = tmp_path / "repo" / "Pipelines" / "Hamner"
    hamner.mkdir(parents=True)
    for name in ("FullBodyModel_Hamner2010_v2_0.osim", "Setup_Scale.xml", "Setup_IK.xml", "subject02_static.trc",
                 "subject02_running.trc", "External_Loads.xml", "subject02_running_grf.mot", "Actuators_RRA.xml",
                 "Tasks_RRA.xml"):
        (hamner / name).write_text("placeholder")  # every file but Setup_RRA.xml
    script = str(ROOT / "scripts" / "bench_dynamics.py")
    for args, needle in (([], "no --opensim-models given"), (["--opensim-models", str(tmp_path / "repo")],
                                                               str(hamner / "Setup_RRA.xml"))):
        proc = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and needle in lines[0] and "not found" in lines[0], lines


def test_bench_length_refuses_lengths_it_cannot_time(tmp_path):
    """bench_length's --lengths: not whole numbers, or shorter than 30 frames (its warm-up's length): one line, exit 2,
    nothing run; the running cases without an opensim-models checkout likewise."""
    import subprocess

    script = str(ROOT / "scripts" / "bench_length.py")
    for args, needle in ((["--lengths", "60,abc"], "give whole numbers of frames"),
                         (["--lengths", "10,60"], "30 frames or more"),
                         (["--only", "hamner"], "not found")):
        proc = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and needle in lines[0], lines


def test_bench_expert_refuses_what_it_cannot_run(tmp_path):
    """bench_expert without an AddBiomechanics checkout, with an unknown case or a config file calibrate does not
    read: one line, exit 2, nothing run."""
    import subprocess

    script = str(ROOT / "scripts" / "bench_expert.py")
    (tmp_path / "paper_data").mkdir()
    (tmp_path / "bad.toml").write_text("[priors]\nmarker_cm = 1\n")
    for args, needle in ((["--addbiomechanics", str(tmp_path / "nowhere")], "no paper_data folder"),
                         (["--addbiomechanics", str(tmp_path), "--cases", "Expert9"], "unknown case 'Expert9'"),
                         (["--addbiomechanics", str(tmp_path), "--config", str(tmp_path / "bad.toml")], "marker_cm"),
                         (["--addbiomechanics", str(tmp_path), "--config", str(tmp_path / "none.toml")],
                          "no such config file")):
        proc = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, timeout=120,
                              cwd=tmp_path)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 2 and len(lines) == 1 and needle in lines[0], lines


def test_bench_expert_all_trials_takes_every_trial_with_the_experts_ik(tmp_path):
    """--all-trials: each trial with both the expert's .mot and a .trc, the static left out (it is calibrated with
    each), sorted; without it, the case's chosen few."""
    import bench_expert as be  # (the scripts folder is on the path, above)

    for name in ("walk2.mot", "walk2.trc", "jump.mot", "jump.trc", "static1.trc", "static1.mot", "squat.mot"):
        (tmp_path / name).write_text("")
    case = {"static": "static1", "trials": ("walk2",)}
    assert be.trials_of(tmp_path, case, every=True) == ("jump", "walk2")
    assert be.trials_of(tmp_path, case, every=False) == ("walk2",)


def test_bench_expert_consistency_spreads_the_statics_angles_over_a_subjects_calibrations():
    """consistency: per subject with a static and two or more calibrations, each coordinate's static mean as they
    read it, its SD and range over them (a subject without a static, or with one calibration, has none)."""
    import bench_expert as be

    reads, offsets = [1.0, 4.0, -2.5], [3.0, -1.0, 0.5]
    rows = [{"subject": "A", "static": "s1", "static_angles_deg": {"ankle_angle_r": v, "knee_angle_r": 2.0},
             "angles": {"ankle_angle_r": {"offset_deg": o, "rms_deg": abs(o)}}}
            for v, o in zip(reads, offsets, strict=True)]
    rows += [{"subject": "B", "static": None, "static_angles_deg": {}},
             {"subject": "C", "static": "s", "static_angles_deg": {"ankle_angle_r": 9.0}}]
    got = be.consistency(rows)
    assert set(got) == {"A"} and got["A"]["calibrations"] == 3 and got["A"]["static"] == "s1"
    ankle = got["A"]["coordinates"]["ankle_angle_r"]
    assert ankle["sd_deg"] == pytest.approx(float(np.std(reads)))
    assert (ankle["min_deg"], ankle["max_deg"]) == (-2.5, 4.0)
    assert ankle["offset_sd_deg"] == pytest.approx(float(np.std(offsets)))
    assert got["A"]["coordinates"]["knee_angle_r"]["sd_deg"] == 0.0
    assert got["A"]["coordinates"]["knee_angle_r"]["offset_sd_deg"] is None  # no offsets given for it


def test_bench_pose2sim_points_the_setups_at_its_files_and_refuses_a_repository_without_the_demo(tmp_path):
    """Pose2Sim's setups name its demo's folders; bench_pose2sim rewrites the model, trial and output file names to
    the files it extracted (ScaleTool and IK read them from the setup's folder), and a repository without the demo's
    commit is refused with one line."""
    import bench_pose2sim

    (tmp_path / "scale_setup.xml").write_text(
        "<ScaleTool><GenericModelMaker><model_file>Unassigned</model_file></GenericModelMaker>"
        "<ModelScaler><marker_file>../Demo/a/pose-3d/static.trc</marker_file><output_model_file>Unassigned"
        "</output_model_file></ModelScaler><MarkerPlacer><marker_file>../Demo/a/static.trc</marker_file>"
        "<output_model_file>../Demo/x_scaled.osim</output_model_file></MarkerPlacer></ScaleTool>")
    (tmp_path / "ik_setup.xml").write_text(
        "<InverseKinematicsTool><model_file>../Demo/x_scaled.osim</model_file><marker_file>../Demo/b.trc"
        "</marker_file><output_motion_file>../Demo/b.mot</output_motion_file></InverseKinematicsTool>")
    bench_pose2sim.adapt_setups(tmp_path)
    scale, ik = (tmp_path / "scale_setup.xml").read_text(), (tmp_path / "ik_setup.xml").read_text()
    assert "<model_file>model.osim</model_file>" in scale and scale.count("<marker_file>static.trc</marker_file>") == 2
    assert scale.count("<output_model_file>scaled.osim</output_model_file>") == 2 and "../Demo" not in scale
    assert ("<model_file>scaled.osim</model_file>" in ik and "<marker_file>balancing.trc</marker_file>" in ik
            and "<output_motion_file>ik.mot</output_motion_file>" in ik)
    empty = tmp_path / "repo"
    import subprocess

    subprocess.run(["git", "init", "-q", str(empty)], check=True)
    with pytest.raises(SystemExit, match="a948c205"):
        bench_pose2sim.read_files(empty, "a948c205", tmp_path)


def test_bench_import_against_opensim_on_the_hand_made_spine(tmp_path):
    """bench_import's figures on the lumped spine of tests/test_osim_lumped.py: the markers above the chain exact,
    the chain's within the bound the import reported (OpenSim in a child process)."""
    import importlib.util

    if importlib.util.find_spec("opensim") is None:
        pytest.skip("opensim is not installed")
    import bench_import

    from tests.test_osim_lumped import spine_osim

    path = tmp_path / "spine.osim"
    path.write_text(spine_osim())
    res = bench_import.import_check(path, lambda m: None, poses_n=12)
    (lumped,) = [a for a in res["approximations"] if a["kind"] == "lumped chain"]
    ms = res["markers_mm"]
    assert max(ms[m]["max"] for m in ("pelvis0", "pelvis1", "pelvis2")) < 1e-3
    assert max(ms[m]["max"] for m in lumped["markers"]) <= lumped["bound_mm"] + 1e-3
    assert lumped["ratios"] and lumped["one_coordinate_mm"] < lumped["max_marker_mm"]


def test_bench_import_on_a_model_welded_to_ground(tmp_path):
    """A ground joint that is not six coordinates (Arm26's weld) is the import's floating base: bench_import puts the
    root segment where OpenSim puts its body and compares the markers below it (before, it gave the floating base a
    random pose that OpenSim's weld never takes: metres apart).  The hand-made model with its FreeJoint welded."""
    import importlib.util

    if importlib.util.find_spec("opensim") is None:
        pytest.skip("opensim is not installed")
    import re

    import bench_import

    from tests.test_osim_import import hand_made_osim

    text = hand_made_osim()
    free = re.search(r'<FreeJoint name="ground_pelvis">.*?</FreeJoint>', text, re.S).group(0)
    weld = re.sub(r"<coordinates>.*</coordinates>", "", free, flags=re.S).replace("FreeJoint", "WeldJoint")
    path = tmp_path / "welded.osim"
    path.write_text(text.replace(free, weld))
    res = bench_import.import_check(path, lambda m: None, poses_n=12)
    ms = res["markers_mm"]
    below = {m for a in res["approximations"] for m in a["markers"]}
    exact = [m for m in ms if m not in below]
    assert len(exact) >= 5 and max(ms[m]["max"] for m in exact) < 1e-3


def test_a_coordinate_coupled_to_another_joints_is_measured_over_that_joints_range(tmp_path):
    """MoBL-ARMS's shoulder: shoulder1 turns by its own shoulder_elv and by shoulder1_r2 = -elv_angle, shoulder0's
    coordinate.  The hinge fit holds shoulder1_r2 at its reference; measured over shoulder_elv alone, the import
    reported 0 mm where OpenSim's hand moves 180 mm.  Here a two-joint arm with that pattern: the reported effect
    must cover what OpenSim shows at random poses (the approximation the model's only one), within its bound."""
    import importlib.util

    if importlib.util.find_spec("opensim") is None:
        pytest.skip("opensim is not installed")
    import bench_import

    from tests.test_osim_import import _BODY, _c, _coords, _frames, _lin, _ta, ground_free

    bodies = "".join(_BODY.format(name=n, mass=m) for n, m in [("trunk", 10), ("upper", 2), ("arm", 2)])
    joints = (
        ground_free("trunk", "0 0 0", prefix="t")
        + f"<PinJoint name=\"plane\">{_frames('trunk', 'upper', '0 0.4 0.17', '0 0 0')}"
        f"{_coords(('elv_angle', -1.5, 2.0))}</PinJoint>"
        f"<CustomJoint name=\"elevate\">{_frames('upper', 'arm', '0 0 0', '0 0 0')}"
        f"{_coords(('shoulder_elv', 0, 2.5), ('elevate_r2', -99, 99))}<SpatialTransform>"
        + _ta("rotation1", "1 0 0", "shoulder_elv", _lin()) + _ta("rotation2", "0 1 0", "elevate_r2", _lin())
        + _ta("rotation3", "0 0 1", "", _c()) + _ta("translation1", "1 0 0", "", _c())
        + _ta("translation2", "0 1 0", "", _c()) + _ta("translation3", "0 0 1", "", _c())
        + "</SpatialTransform></CustomJoint>")
    markers = "".join(
        f"<Marker name=\"{n}\"><socket_parent_frame>/bodyset/{b}</socket_parent_frame><location>{loc}</location>"
        f"</Marker>" for n, b, loc in [("T1", "trunk", "0.1 0 0"), ("T2", "trunk", "0 0.2 0"),
                                      ("T3", "trunk", "0 0 0.1"), ("ELB", "arm", "0.02 -0.3 0.04"),
                                      ("HAND", "arm", "-0.03 -0.55 0.05")])
    coupler = ("<CoordinateCouplerConstraint name=\"elevate_con\"><isEnforced>true</isEnforced>"
               "<coupled_coordinates_function>" + _lin(-1, 0).replace(' name="function"', "")
               + "</coupled_coordinates_function><independent_coordinate_names>elv_angle"
               "</independent_coordinate_names><dependent_coordinate_name>elevate_r2</dependent_coordinate_name>"
               "<scale_factor>1</scale_factor></CoordinateCouplerConstraint>")
    path = tmp_path / "shoulder.osim"
    path.write_text("<?xml version=\"1.0\" encoding=\"UTF-8\" ?>\n<OpenSimDocument Version=\"40000\">"
                    "<Model name=\"shoulder\"><Ground name=\"ground\"/><gravity>0 -9.80665 0</gravity>"
                    f"<BodySet name=\"bodyset\"><objects>{bodies}</objects></BodySet>"
                    f"<JointSet name=\"jointset\"><objects>{joints}</objects></JointSet>"
                    f"<ConstraintSet name=\"constraintset\"><objects>{coupler}</objects></ConstraintSet>"
                    f"<MarkerSet name=\"markerset\"><objects>{markers}</objects></MarkerSet></Model>"
                    "</OpenSimDocument>\n")
    res = bench_import.import_check(path, lambda m: None, poses_n=40)
    (fit,) = res["approximations"]
    assert fit["joint"] == "elevate" and fit["kind"] == "hinge fit"
    ms = res["markers_mm"]
    seen = max(ms[m]["max"] for m in fit["markers"])  # OpenSim against the import at 40 random poses
    assert seen > 50  # the approximation moves the hand a lot ...
    assert fit["max_marker_mm"] >= 0.9 * seen and seen <= fit["bound_mm"]  # ... and the import says so
    assert max(ms[m]["max"] for m in ("T1", "T2", "T3")) < 1e-6


def test_the_approximations_together_against_opensim(tmp_path):
    """A marker below several approximated joints (here the hand-made model's patella hung from the shank: the
    knee's hinge fit and the patella's weld above it; MoBL-ARMS's hand: four welded girdle joints and a hinge fit,
    613 mm) moves by their joint effect, which no per-joint figure states: the import measures it
    (OsimInfo.together) at its own random poses, and OpenSim at bench_import's agrees (a largest displacement of the
    same size)."""
    import importlib.util

    if importlib.util.find_spec("opensim") is None:
        pytest.skip("opensim is not installed")
    import re

    import bench_import

    from calibrate.io.osim_info import import_summary, osim_info
    from calibrate.model.model import load_model
    from tests.test_osim_import import hand_made_osim

    text = hand_made_osim()
    patfem = re.search(r'<CustomJoint name="patfem">.*?</CustomJoint>', text, re.S).group(0)
    path = tmp_path / "handmade.osim"
    path.write_text(text.replace(patfem, patfem.replace("/bodyset/thigh", "/bodyset/shank").replace(
        "thigh_off", "shank_off")))
    info = osim_info(load_model(path))
    t = info.together
    assert t is not None and "patella" in t.marker and t.poses > 0
    # the calibration's note says it beside each joint's figure
    assert f"together up to {t.max_marker_mm:.0f} mm at {t.marker}, below several of them" in import_summary(info)
    res = bench_import.import_check(path, lambda m: None, poses_n=100)
    below = {}
    for a in res["approximations"]:
        for m in a["markers"]:
            below[m] = below.get(m, 0) + 1
    stacked = [m for m, k in below.items() if k >= 2]
    seen = max(res["markers_mm"][m]["max"] for m in stacked)
    assert 0.9 * t.max_marker_mm <= seen <= 1.1 * t.max_marker_mm  # 32.2 mm against 32.3
    # ... and nothing where no marker is below two approximations (Rajagopal's and gait2392's knees)
    rajagopal = REAL / "rajagopal_walk" / "Rajagopal2016.osim"
    if rajagopal.exists():
        assert osim_info(load_model(rajagopal)).together is None


def test_a_coordinates_segment_markers_are_read_from_the_osim_below_a_bare_segment():
    """attribute_shapes moves the markers of the segment a coordinate turns that the walk shows: the hip's femur
    carries its own; the ankle's talus carries only a joint-centre marker a walk does not show, so the foot's below
    it are taken.  Checked against the .osim's own XML (each marker's socket_parent_frame), not calibrate's reading
    of it."""
    import xml.etree.ElementTree as ET

    osim = CASES["rajagopal"][0]
    if not osim.exists():
        pytest.skip(f"{osim} not found (the real trials)")
    on: dict[str, set[str]] = {}
    for m in ET.parse(osim).getroot().iter("Marker"):
        on.setdefault(m.findtext("socket_parent_frame").strip().rsplit("/", 1)[-1], set()).add(m.get("name"))
    shown = set().union(*on.values()) - on["talus_l"]  # a walk: no ankle-centre marker
    model = load_model(osim)
    segment, names = bench_osim._segment_markers(model, "femur_l", shown)
    assert segment == "femur_l" and set(names) == on["femur_l"] and names
    segment, names = bench_osim._segment_markers(model, "talus_l", shown)
    assert segment == "calcn_l" and set(names) == on["calcn_l"]
    segment, names = bench_osim._segment_markers(model, "talus_l", set().union(*on.values()))
    assert segment == "talus_l" and set(names) == on["talus_l"]  # shown, the talus's own
