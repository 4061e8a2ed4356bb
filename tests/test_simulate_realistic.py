"""What a lab adds to a simulated trial: soft-tissue artefact, overhead motion, stature, gaps as a
fraction, swapped labels and spikes (with their ground truth), simulate_realistic and the CLI flags.

Independent references: Pinocchio on the truth URDF written by the simulator, driven by its motion."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from calibrate.cli import main
from calibrate.model.model import load_model
from calibrate.simulation.artefacts import STA_ACROMION, STA_FACTOR, STA_SPREAD, read_corruptions
from calibrate.simulation.simulate import (
    simulate_gait,
    simulate_overhead,
    simulate_realistic,
    simulate_squats,
    write_simulation,
)


def _pin_subject(sim, tmp_path):
    """The subject's Model read back from the truth URDF the simulator writes."""
    write_simulation(sim, tmp_path)
    return load_model(tmp_path / "truth.urdf")


def _placements(subject, motion, frames, names):
    """World placements (pin.SE3) of the named frames (segments, markers) in the given frames."""
    d = subject.pin.createData()
    fids = {n: subject.pin.getFrameId(n, pin.FrameType.BODY) for n in names}
    out = []
    for f in frames:
        q = subject.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.framesForwardKinematics(subject.pin, d, q)
        out.append({n: d.oMf[i].copy() for n, i in fids.items()})
    return out


def _kind(segment: str) -> str:
    return "_".join(p for p in segment.split("_") if p not in ("r", "l"))


def test_soft_tissue_artefact_moves_markers_on_their_bones_by_segment(human, tmp_path):
    """Markers seen in their segment's frame (Pinocchio, truth URDF + motion) move off their bone
    position by at most their amplitude, thigh far more than shank, smoothly in time; the truth
    files give the bone model's markers (clean_markers), not the skin's."""
    x_mm = 10.0
    sim = simulate_squats(human, frames=150, seed=2, noise_mm=0.0, sta_mm=x_mm)
    subject = _pin_subject(sim, tmp_path)
    names = [s.name for s in subject.segments] + list(subject.marker_names)
    frames = range(sim.trial.n_frames)
    placements = _placements(subject, sim.motion, frames, names)
    dev = np.zeros((len(frames), len(subject.markers), 3))
    for f, pl in zip(frames, placements, strict=True):
        for k, mk in enumerate(subject.markers):
            seg = pl[mk.segment]
            bone = pl[mk.name].translation
            assert np.allclose(bone, sim.clean_markers[f, k], atol=1e-9)  # truth = bone model
            dev[f, k] = seg.rotation.T @ (sim.trial.markers[f, k] - bone)  # skin vs bone, segment frame
    size = np.linalg.norm(dev, axis=2)
    peak = size.max(axis=0)
    amp = sim.sta_amplitude
    assert np.all(size <= amp[None, :] + 1e-9)  # |d| <= a by construction
    for k, mk in enumerate(subject.markers):
        kind = _kind(mk.segment)
        top = STA_ACROMION if kind == "torso" else STA_FACTOR[kind]  # acromion markers ride on the scapula
        assert x_mm * 1e-3 * STA_FACTOR[kind] * STA_SPREAD[0] - 1e-12 <= amp[k] <= x_mm * 1e-3 * top * STA_SPREAD[1]

    def median_peak(kind):
        return float(np.median([peak[k] for k, mk in enumerate(subject.markers) if _kind(mk.segment) == kind]))

    thigh, shank, pelvis = median_peak("femur"), median_peak("tibia"), median_peak("pelvis")
    assert 0.008 <= thigh <= 0.030, thigh  # 10-30 mm at the thigh for X = 10 mm (squats reach most of it)
    assert thigh > 1.5 * shank and shank > 0.002, (thigh, shank)
    assert pelvis < 0.5 * thigh, (pelvis, thigh)
    # smooth in time: second differences tiny against the excursion (white noise would be ~2-4x it)
    d2 = np.abs(np.diff(dev, 2, axis=0)).max(axis=0).max(axis=1)
    moving = peak > 1e-3
    assert np.all(d2[moving] < 0.01 * peak[moving]), (d2 / np.maximum(peak, 1e-12)).max()
    np.testing.assert_allclose(sim.trial.markers - sim.clean_markers, sim.artefact, atol=1e-12)


def test_overhead_arms_pass_the_gimbal_lock_far_above_the_head(human, tmp_path):
    """Shoulder elevation measured geometrically (humerus long axis vs the torso's downward axis, from
    Pinocchio's segment placements) above 150 deg on both sides, the adduction coordinate going
    continuously through -90 deg (flexion and rotation axes aligned), angles within the model's limits,
    the rest of the body in smaller arcs; Pinocchio's markers are the simulator's noise-free ones."""
    sim = simulate_overhead(human, frames=600, seed=1, noise_mm=0.5)
    subject = _pin_subject(sim, tmp_path)
    frames = range(0, 600, 2)
    names = ["torso", "humerus_r", "ulna_r", "humerus_l", "ulna_l"] + list(subject.marker_names)
    placements = _placements(subject, sim.motion, frames, names)
    for side in ("r", "l"):
        elev = []
        for pl in placements:
            arm = pl[f"ulna_{side}"].translation - pl[f"humerus_{side}"].translation  # shoulder -> elbow
            down = -pl["torso"].rotation[:, 2]
            elev.append(np.degrees(np.arccos(arm @ down / np.linalg.norm(arm))))
        assert max(elev) > 150.0, (side, max(elev))
        assert min(elev) < 40.0  # and back down between arcs
        add = np.degrees(sim.motion.angles[:, human.dof_index(f"shoulder_{side}_adduction")])
        assert add.min() < -150 and add.max() > -30  # through -90 deg (gimbal lock) and back
    worst = max(np.abs(pl[m.name].translation - sim.clean_markers[f, k]).max()
                for f, pl in zip(frames, placements, strict=True) for k, m in enumerate(subject.markers))
    assert worst < 1e-9
    a = sim.motion.angles
    assert np.degrees(np.abs(np.diff(a, axis=0))).max() < 4.0  # continuous: < 4 deg per frame at 100 Hz
    lo, hi = np.array([d.lower for d in human.dofs]), np.array([d.upper for d in human.dofs])
    assert np.all(a >= lo - 1e-12) and np.all(a <= hi + 1e-12)
    rom = np.degrees(np.ptp(a, axis=0))
    for name in ("hip_r_flexion", "knee_l", "lumbar_flexion"):
        assert 15 <= rom[human.dof_index(name)] <= 60, (name, rom[human.dof_index(name)])
    # the subject is simulate_squats' for the seed
    np.testing.assert_array_equal(sim.truth.vector(), simulate_squats(human, frames=5, seed=1).truth.vector())


@pytest.mark.parametrize("height", [1.5, 2.0])
def test_height_sets_the_stature_with_varied_proportions(human, tmp_path, height):
    """Stature from Pinocchio's neutral pose of the truth URDF: neck centre above the ankle centres plus
    calibrate.model.human's sole-to-ankle (0.07/1.75) and neck-to-vertex (0.25/1.75) heights scaled by the feet
    and head; within 1 mm of the request.  The head markers sit where a 1.5 or 2.0 m subject's do."""
    sim = simulate_squats(human, frames=10, seed=4, height=height)
    subject = _pin_subject(sim, tmp_path)
    d = subject.pin.createData()
    pin.framesForwardKinematics(subject.pin, d, subject.pin_configuration(np.zeros(3), [0, 0, 0, 1],
                                                                           np.zeros(subject.n_dofs)))

    def z(name):
        return d.oMf[subject.pin.getFrameId(name, pin.FrameType.BODY)].translation[2]

    s = sim.truth.scale
    seg = {sg.name: i for i, sg in enumerate(human.segments)}
    ankle = 0.5 * (z("talus_r") + z("talus_l"))
    sole = ankle - 0.07 * 0.5 * (s[seg["calcn_r"]] + s[seg["calcn_l"]])  # base model: 1.75 m, sole at 0
    vertex = z("head") + 0.25 * s[seg["head"]]
    assert abs((vertex - sole) - height) < 1e-3
    assert sim.stature == pytest.approx(height, abs=1e-9)
    head = np.mean([z(n) for n in ("RFHD", "LFHD", "RBHD", "LBHD")]) - sole
    assert 0.94 <= head / height <= 0.985  # 1.685 of 1.75 m in the base model
    ratio = s / s.mean()
    assert ratio.max() / ratio.min() <= 1.04 / 0.96 + 1e-9 and ratio.max() / ratio.min() > 1.03  # ±4 % each
    # only the scales change: the motion, centres, axes and markers are the seed's
    plain = simulate_squats(human, frames=10, seed=4)
    np.testing.assert_array_equal(sim.motion.angles, plain.motion.angles)
    for block in ("centre", "axis", "marker"):
        np.testing.assert_array_equal(getattr(sim.truth, block), getattr(plain.truth, block))
    assert plain.stature is None


def test_swaps_and_spikes_are_exactly_the_listed_samples(human, tmp_path):
    """Without noise, the observed markers differ from the clean ones exactly at the samples the
    corruptions list (and its CSV) names: swaps carry the partner's position, spikes 30-100 mm errors."""
    sim = simulate_squats(human, frames=200, seed=3, noise_mm=0.0, swaps=3, spikes=5, gap_fraction=0.05)
    obs, clean = sim.trial.markers, sim.clean_markers
    visible = ~np.isnan(obs[..., 0])
    differ = visible & (np.abs(obs - clean).max(axis=2) > 1e-12)
    listed = {(c.frame, human.marker_index(c.marker)) for c in sim.corruptions}
    assert {tuple(x) for x in np.argwhere(differ)} == listed
    assert all(visible[f, k] for f, k in listed)  # never on a gap
    kinds = [c.kind for c in sim.corruptions]
    assert kinds.count("spike") == 5
    episodes = {}
    adjacent = {(j.parent, j.child) for j in human.joints} | {(j.child, j.parent) for j in human.joints}
    for c in sim.corruptions:
        f, k = c.frame, human.marker_index(c.marker)
        if c.kind == "spike":
            assert 0.030 <= c.error <= 0.100 and np.linalg.norm(obs[f, k] - clean[f, k]) == pytest.approx(c.error)
        else:
            j = human.marker_index(c.partner)
            np.testing.assert_array_equal(obs[f, k], clean[f, j])
            assert c.error == pytest.approx(np.linalg.norm(clean[f, j] - clean[f, k]))
            a, b = human.markers[k].segment, human.markers[j].segment
            assert a == b or (a, b) in adjacent
            episodes.setdefault(frozenset((c.marker, c.partner)), set()).add(f)
    runs = sum(1 + int(np.sum(np.diff(sorted(fs)) > 1)) for fs in episodes.values())
    assert runs == 3 and all(3 <= len(fs) for fs in episodes.values())
    paths = write_simulation(sim, tmp_path)
    back = read_corruptions(paths["corruptions"])
    assert [(c.kind, c.frame, c.marker, c.partner) for c in back] == [
        (c.kind, c.frame, c.marker, c.partner) for c in sim.corruptions]
    np.testing.assert_allclose([c.error for c in back], [c.error for c in sim.corruptions], atol=1e-6)


def test_gap_fraction_and_options_leave_the_rest_of_the_trial_alone(human):
    """gap_fraction: that share of the samples in gaps of 0.05-0.6 s; turning the options on changes
    nothing else (same subject, motion, noise: the option streams are separate), in squats and gait."""
    sim = simulate_squats(human, frames=400, seed=1, gap_fraction=0.05)
    gap = np.isnan(sim.trial.markers[..., 0])
    assert 0.05 <= gap.mean() <= 0.05 + 60 / gap.size
    for k in range(gap.shape[1]):
        edges = np.flatnonzero(np.diff(np.r_[0, gap[:, k].astype(int), 0]))
        lengths = edges[1::2] - edges[0::2]
        assert np.all(lengths >= 5)  # 0.05 s at 100 Hz; overlapping gaps merge into longer ones
    assert gap.mean(axis=0).max() <= 0.2 + 1e-9
    for simulate in (simulate_squats, simulate_gait):
        plain = simulate(human, frames=80, seed=6)
        again = simulate(human, frames=80, seed=6, sta_mm=0.0, height=None, swaps=0, spikes=0, gap_fraction=0.0)
        np.testing.assert_array_equal(plain.trial.markers, again.trial.markers)
        lab = simulate(human, frames=80, seed=6, sta_mm=4.0, swaps=1, spikes=2)
        for a, b in ((plain.motion.angles, lab.motion.angles), (plain.clean_markers, lab.clean_markers),
                     (plain.truth.vector(), lab.truth.vector())):
            np.testing.assert_array_equal(a, b)
        bad = np.zeros(plain.trial.markers.shape[:2], dtype=bool)
        for c in lab.corruptions:
            bad[c.frame, human.marker_index(c.marker)] = True
        np.testing.assert_allclose((lab.trial.markers - lab.artefact)[~bad], plain.trial.markers[~bad], atol=1e-12)
        assert plain.artefact is None and plain.corruptions == ()


def test_realistic_combination_and_cli(human, tmp_path, capsys):
    sim = simulate_realistic(human, seed=5, frames=200)
    assert 1.5 <= sim.stature <= 2.0
    assert 0.05 <= np.isnan(sim.trial.markers[..., 0]).mean() <= 0.06
    assert [c.kind for c in sim.corruptions].count("spike") == 5
    assert np.linalg.norm(sim.artefact, axis=2).max() <= 3e-3 * 2.5 * 1.5 + 1e-12
    rom = np.degrees(np.ptp(sim.motion.angles, axis=0))
    assert rom[human.dof_index("hip_r_flexion")] > 50 and rom[human.dof_index("knee_r")] > 50  # one squat in 2 s
    out = tmp_path / "r"
    assert main(["simulate", "--out", str(out), "--frames", "120", "--realistic", "--seed", "5", "--sta-mm", "2",
                 "--height", "1.62"]) == 0
    text = capsys.readouterr().out
    assert "stature 1.620 m" in text and "truth_corruptions.csv" in text
    rows = read_corruptions(out / "truth_corruptions.csv")
    again = simulate_realistic(human, seed=5, frames=120, sta_mm=2.0, height=1.62)
    assert [(c.frame, c.marker) for c in rows] == [(c.frame, c.marker) for c in again.corruptions]
    # plain runs keep today's outputs: no corruptions file
    assert main(["simulate", "--out", str(tmp_path / "p"), "--frames", "20", "--motion", "overhead"]) == 0
    assert not (tmp_path / "p" / "truth_corruptions.csv").exists()


@pytest.mark.parametrize("argv, needle", [
    (["--height", "2.5"], "0.9-2.2"),
    (["--height", "tall"], "stature in metres"),
    (["--sta-mm", "-1"], "zero or positive"),
    (["--swaps", "-2"], "zero or positive"),
    (["--spikes", "1.5"], "whole number"),
    (["--gap-fraction", "0.7"], "0-0.5"),
    (["--motion", "jump"], "invalid choice"),
])
def test_cli_bad_values_one_line_exit_2(tmp_path, capsys, argv, needle):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--out", str(tmp_path / "x"), *argv])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("calibrate simulate: error:") and needle in err[0], err
    assert not (tmp_path / "x").exists()


def test_cli_impossible_request_one_line(tmp_path, capsys):
    assert main(["simulate", "--out", str(tmp_path / "x"), "--frames", "5", "--swaps", "40"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("calibrate: error: simulate: swaps:"), err
