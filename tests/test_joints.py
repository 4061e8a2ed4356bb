"""Joint-centre estimation (calibrate.seed.joints, calibrate.seed.geometry): closed forms, the MTB framework on
synthetic chains (seed 000 Section IV) and on simulated squats of models/human.urdf, and the CLI."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.cli import main
from calibrate.io.trial import Trial
from calibrate.seed.geometry import rigid_fit, similarity_fit, sphere_fit
from calibrate.seed.joints import (
    JointSpec,
    butter_lowpass,
    estimate_joints,
    estimate_model_joints,
    filtfilt,
    lowpass,
    lowpass_each,
)
from calibrate.seed.mtb import affine_basis, auxiliary_point, jmv_cost, jmv_frames, mtb_refine, rigid_basis
from calibrate.simulation.chains import simulate_chain
from calibrate.simulation.simulate import joint_axes_world, simulate_squats, write_simulation

CHAINS = {1: (4, 3, 3), 2: (4, 3, 3, 4, 3), 3: (4, 3, 3, 4, 3, 3, 3, 3), 4: (3, 2, 2, 2, 2), 5: (3, 1, 2, 2, 2, 2)}


def rse(est, truth: np.ndarray) -> float:
    """Seed 000 Eq. 10: sqrt of the summed squared errors over frames and joints, over M·F."""
    c = est.centres()
    F, M, _ = c.shape
    return float(np.sqrt(np.sum((c - truth) ** 2)) / (M * F))


def random_motion(F: int, rng: np.random.Generator) -> np.ndarray:
    """Rotations (F, 3, 3) that wander in 3-D (not about one axis)."""
    t = np.linspace(0, 1, F)[:, None]
    rv = np.hstack([np.sin(2 * np.pi * (rng.uniform(0.3, 1.0) * t + rng.uniform())) for _ in range(3)])
    return Rotation.from_rotvec(rv * rng.uniform(0.6, 1.2, 3)).as_matrix()


# ------------------------------------------------------------------ closed forms
def test_rigid_fit_recovers_poses_and_shape_through_gaps():
    rng = np.random.default_rng(1)
    local = rng.normal(size=(5, 3)) * 0.1
    R = Rotation.random(60, random_state=3).as_matrix()
    t = rng.normal(size=(60, 3))
    world = np.einsum("fij,pj->fpi", R, local) + t[:, None]
    world[7, 2] = np.nan
    world[8, :2] = np.nan
    fit = rigid_fit(world)
    back = fit.to_world(fit.local)
    seen = np.isfinite(world)
    assert np.max(np.abs(back[seen] - world[seen])) < 1e-12
    # shape: pairwise distances of the fitted local points equal the true ones
    d_true = np.linalg.norm(local[:, None] - local[None], axis=2)
    d_fit = np.linalg.norm(fit.local[:, None] - fit.local[None], axis=2)
    assert np.max(np.abs(d_true - d_fit)) < 1e-12
    # collinear points give no frame
    line = np.zeros((10, 3, 3))
    line[:, 1, 0], line[:, 2, 0] = 1.0, 2.0
    assert not rigid_fit(line).valid.any()


def test_sphere_fit_ball_and_hinge_closed_forms():
    rng = np.random.default_rng(2)
    centre = np.array([0.1, -0.2, 0.3])
    pts_local = rng.normal(size=(3, 3)) * 0.2
    R = random_motion(200, rng)
    ball = np.einsum("fij,pj->fpi", R, pts_local) + centre
    fit = sphere_fit(ball)
    assert np.linalg.norm(fit.centre - centre) < 1e-12
    assert fit.rms < 1e-12 and fit.hinge_ratio > 0.01
    axis = np.array([0.2, 0.9, -0.3]) / np.linalg.norm([0.2, 0.9, -0.3])
    Rh = Rotation.from_rotvec(np.linspace(0, 1.8, 200)[:, None] * axis).as_matrix()
    hinge = np.einsum("fij,pj->fpi", Rh, pts_local) + centre
    near = centre + 0.37 * axis + np.array([0.05, 0.0, 0.0])
    fit = sphere_fit(hinge, hinge=True, near=near)
    assert fit.hinge_ratio < 1e-12
    assert abs(abs(fit.axis @ axis) - 1) < 1e-12
    # the chosen centre is on the axis, at the foot of the perpendicular from `near`
    expect = centre + axis * (axis @ (near - centre))
    assert np.linalg.norm(fit.centre - expect) < 1e-10


def test_similarity_fit_recovers_scale_rotation_translation():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(6, 3))
    R = Rotation.random(random_state=4).as_matrix()
    dst = 1.13 * src @ R.T + np.array([1.0, 2.0, 3.0])
    s, Rf, t = similarity_fit(src, dst)
    assert abs(s - 1.13) < 1e-12 and np.max(np.abs(Rf - R)) < 1e-12 and np.max(np.abs(t - [1, 2, 3])) < 1e-12


def test_affine_basis_is_exact_for_a_point_fixed_on_the_segment():
    """Seed 000 Eq. 5/6: a point rigid with the markers is one fixed λ for every frame (4 markers, and
    3 markers plus the auxiliary point of Eq. 9)."""
    rng = np.random.default_rng(4)
    local = rng.normal(size=(4, 3)) * 0.2
    joint = np.array([0.3, -0.1, 0.2])
    R = Rotation.random(50, random_state=5).as_matrix()
    t = rng.normal(size=(50, 3))
    world = np.einsum("fij,pj->fpi", R, local) + t[:, None]
    truth = R @ joint + t
    for pts in (world, world[:, :3]):
        basis = affine_basis(pts)
        assert basis.kind == "affine"
        lam = np.linalg.solve(basis.B[0], truth[0] - basis.o[0])
        assert np.max(np.abs(basis.point(lam) - truth)) < 1e-12
    aux = auxiliary_point(world[:, 0], world[:, 1], world[:, 2])
    d = np.linalg.norm(aux - world[:, 0], axis=1)
    assert np.ptp(d) < 1e-12  # the auxiliary point is rigid with the three markers


@pytest.mark.parametrize("alpha", [0.0, 0.05])
def test_mtb_refine_reaches_a_stationary_point_of_eq8(alpha):
    """Newton on λ: the returned λ makes the finite-difference gradient of the Eq. 8 cost (computed
    by jmv_cost, an independent formula) vanish, and lowers the cost from a perturbed start."""
    rng = np.random.default_rng(5)
    F = 120
    R = random_motion(F, rng)
    Ra = random_motion(F, rng)
    ta = rng.normal(size=(F, 3)) * 0.1
    a_local = rng.normal(size=(4, 3)) * 0.15
    joint = np.array([0.0, 0.0, -0.4])
    A = np.einsum("fij,pj->fpi", Ra, a_local) + ta[:, None]
    c = Ra @ joint + ta
    b_local = rng.normal(size=(3, 3)) * 0.15 + [0, 0, -0.3]
    B = np.einsum("fij,fjk,pk->fpi", Ra, R, b_local) + c[:, None]
    noisy = np.concatenate([A, B], axis=1) + rng.normal(0, 1e-3, (F, 7, 3))
    basis = rigid_basis(rigid_fit(noisy[:, :4]))
    lam0 = np.linalg.lstsq(basis.B[0], c[0] - basis.o[0], rcond=None)[0] + 0.02
    lam, cost, _ = mtb_refine(basis, noisy, lam0, alpha)

    def q(x):
        return jmv_cost(basis.point(x), noisy, alpha)

    assert cost == pytest.approx(q(lam), rel=1e-9)
    assert q(lam) < q(lam0)
    h = 1e-6
    grad = np.array([(q(lam + h * e) - q(lam - h * e)) / (2 * h) for e in np.eye(3)])
    grad0 = np.array([(q(lam0 + h * e) - q(lam0 - h * e)) / (2 * h) for e in np.eye(3)])
    assert np.linalg.norm(grad) < 1e-6 * np.linalg.norm(grad0)


def test_jmv_frames_recovers_a_joint_without_any_segment_frame():
    """Per-frame JMV (hybrid fallback): two points on each side (no segment has a frame), noise-free."""
    ch = simulate_chain((3, 2, 2), frames=80, seed=7)
    j1 = ch.centres[:, 1]
    pts = np.stack([ch.points()[k] for k in ch.groups["s1"] + ch.groups["s2"]] + [ch.centres[:, 0]], axis=1)
    start = j1 + np.random.default_rng(0).normal(0, 0.05, j1.shape)
    c, rho, rms = jmv_frames(pts, start)
    assert rms < 1e-9
    assert np.max(np.linalg.norm(c - j1, axis=1)) < 1e-7


def test_lowpass_keeps_slow_motion_removes_noise_and_respects_gaps():
    rate, F = 100.0, 1000
    t = np.arange(F) / rate
    clean = np.column_stack([np.sin(2 * np.pi * 0.5 * t), np.cos(2 * np.pi * 0.3 * t), t * 0.1])
    rng = np.random.default_rng(8)
    noisy = clean + rng.normal(0, 1e-3, clean.shape)
    noisy[400:420] = np.nan
    out = lowpass(noisy, rate, 6.0)
    assert np.all(np.isnan(out[400:420])) and np.all(np.isfinite(out[:400]))
    inner = np.r_[50:350, 470:950]
    err = np.sqrt(np.mean((out[inner] - clean[inner]) ** 2))
    assert err < 0.5e-3  # 6 Hz of a 50 Hz band keeps about a third of white noise


def test_lowpass_each_gives_every_markers_own_lowpass_bit_for_bit():
    """The markers filtered together where their gap-free runs coincide (lowpass_each, what the seed
    uses) get exactly the numbers of one lowpass call per marker: markers without gaps, with a gap in the
    middle, two with the same gap, one with a run too short to filter and one never seen."""
    rate, F = 100.0, 300
    rng = np.random.default_rng(4)
    base = np.cumsum(rng.normal(0, 1e-3, (F, 6, 3)), axis=0)
    base[100:110, 2] = np.nan
    base[100:110, 3] = np.nan
    base[:290, 4] = np.nan  # 10 frames left: too short to filter
    base[:, 5] = np.nan
    points = {f"m{i}": base[:, i] for i in range(6)}
    together = lowpass_each(points, rate, 6.0)
    for k, v in points.items():
        alone = lowpass(v, rate, 6.0)
        assert np.array_equal(together[k], alone, equal_nan=True), k
    assert not np.array_equal(together["m0"], points["m0"])  # filtered, not handed back
    assert np.array_equal(together["m4"], points["m4"], equal_nan=True)


@pytest.mark.parametrize("order", [2, 4, 5])
@pytest.mark.parametrize("wn", [0.05, 0.1, 0.5, 0.9])
def test_butterworth_and_zero_phase_filter_equal_scipy_signal(order, wn):
    # Written out to spare every command scipy.signal's import; scipy.signal is the reference.
    from scipy import signal

    b, a = butter_lowpass(order, wn)
    b0, a0 = signal.butter(order, wn)
    np.testing.assert_allclose(b, b0, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(a, a0, rtol=1e-12, atol=1e-15)
    x = np.random.default_rng(order).standard_normal((300, 4, 3)).cumsum(axis=0)  # a wandering trajectory
    ref = signal.filtfilt(b0, a0, x, axis=0)
    np.testing.assert_allclose(filtfilt(b, a, x), ref, rtol=0, atol=1e-9 * np.abs(x).max())


# ------------------------------------------------------------------ chains (seed 000 Section IV)
@pytest.mark.parametrize("chain", [1, 2, 3, 4])
@pytest.mark.parametrize("basis", ["rigid", "affine"])
def test_framework_is_exact_on_noise_free_chains(chain, basis):
    for seed in range(3):
        ch = simulate_chain(CHAINS[chain], frames=100, seed=seed)
        specs = [JointSpec(*j) for j in ch.joints]
        est = estimate_joints(ch.points(), ch.groups, specs, basis=basis)
        assert all(j.ok for j in est)
        assert rse(est, ch.centres) <= 1e-9
        assert est[specs[0].name].method == "MTB"
        assert {j.method for j in est} <= {"MTB", "MTB (propagated)"}


def test_hybrid_scheme_solves_chain_5():
    """⟨3-1-2-2-2-2⟩: the 1-marker segment stops propagation; one JMV step restarts it."""
    errs = []
    for seed in range(5):
        ch = simulate_chain(CHAINS[5], frames=100, seed=seed)
        est = estimate_joints(ch.points(), ch.groups, [JointSpec(*j) for j in ch.joints])
        assert all(j.ok for j in est)
        assert est.order[1] == "j1"  # the JMV step comes right after the first MTB joint
        errs.append(rse(est, ch.centres))
    # Seed 000 Table IV reports 2.8e-2 for its JMV step; ours converges Newton on exact data to
    # machine precision (~1e-15 measured).  1e-9, as for the pure MTB chains: a JMV step stopped
    # early, or a centre biased by the start, is 1e-6 or more off.
    assert max(errs) < 1e-9


def test_noise_gives_errors_of_the_order_of_the_noise():
    ch = simulate_chain(CHAINS[2], frames=200, noise=1e-3, seed=3)
    est = estimate_joints(ch.points(), ch.groups, [JointSpec(*j) for j in ch.joints])
    err = np.linalg.norm(est.centres() - ch.centres, axis=2)
    # 1e-3 marker noise, markers 0.1-0.4 from a segment 1 long: 1.45e-3 measured (each joint
    # 1.25e-3 to 1.86e-3).  3e-3: a 2x regression (a propagated error, an unrefined closed-form
    # start) fails, while the noise of another seed does not.
    assert np.median(err) < 3e-3
    assert np.median(err, axis=0).max() < 4e-3
    assert all(1e-4 < j.rms < 3e-3 for j in est)  # the JMV residual reflects the noise


def test_jmv_mode_baseline_and_reasons():
    ch = simulate_chain(CHAINS[1], frames=100, seed=0)
    est = estimate_joints(ch.points(), ch.groups, [JointSpec(*j) for j in ch.joints], mode="jmv")
    assert {j.method for j in est} == {"JMV"}
    assert rse(est, ch.centres) < 1e-6
    ch5 = simulate_chain(CHAINS[5], frames=100, seed=0)
    est5 = estimate_joints(ch5.points(), ch5.groups, [JointSpec(*j) for j in ch5.joints], mode="jmv")
    bad = est5["j1"]
    assert not bad.ok and bad.method == "failed" and "4 or more points" in bad.reason
    assert np.all(np.isnan(bad.centre))


def test_unestimable_joints_are_reported_with_a_reason():
    ch = simulate_chain(CHAINS[1], frames=100, seed=0)
    pts = ch.points()
    # the child segment frozen relative to its parent: no motion at the joint
    frozen = {k: v.copy() for k, v in pts.items()}
    for lab in ch.groups["s1"]:
        frozen[lab] = pts[lab]
    s0 = np.stack([pts[k] for k in ch.groups["s0"]], axis=1)
    frames = rigid_fit(s0)
    for lab in ch.groups["s1"]:
        local = frames.to_local(pts[lab][:, None, :])[0, 0]
        frozen[lab] = frames.to_world(local)
    est = estimate_joints(frozen, ch.groups, [JointSpec(*j) for j in ch.joints])
    assert not est["j0"].ok and "barely moves" in est["j0"].reason
    # too few frames with the anchor's markers
    gappy = {k: v.copy() for k, v in pts.items()}
    gappy[ch.groups["s0"][0]][5:] = np.nan
    gappy[ch.groups["s0"][1]][5:] = np.nan
    est = estimate_joints(gappy, ch.groups, [JointSpec("j0", "s0", "s1")])
    assert not est["j0"].ok and "only 5 frames see s0's frame" in est["j0"].reason and "need 10" in est["j0"].reason


def test_gaps_are_left_out_frame_by_frame():
    ch = simulate_chain(CHAINS[1], frames=150, seed=2)
    pts = ch.points()
    lab = ch.groups["s1"][0]
    pts[lab][30:60] = np.nan
    est = estimate_joints(pts, ch.groups, [JointSpec(*j) for j in ch.joints])
    ok = np.isfinite(est.centres()[..., 0])
    assert ok.all()  # rigid frames from the remaining points still define every frame
    assert np.max(np.abs(est.centres() - ch.centres)) < 1e-9


def test_bad_arguments_get_precise_errors():
    ch = simulate_chain(CHAINS[1], frames=50, seed=0)
    specs = [JointSpec(*j) for j in ch.joints]
    with pytest.raises(ValueError, match="mode"):
        estimate_joints(ch.points(), ch.groups, specs, mode="fast")
    with pytest.raises(ValueError, match="no trajectory"):
        estimate_joints(ch.points(), {**ch.groups, "s9": ("nope",)}, specs)
    with pytest.raises(ValueError, match="two groups"):
        estimate_joints(ch.points(), {**ch.groups, "s9": (ch.groups["s0"][0],)}, specs)
    with pytest.raises(ValueError, match="kind"):
        estimate_joints(ch.points(), ch.groups, [JointSpec("j0", "s0", "s1", "slider")])
    with pytest.raises(ValueError, match="cutoff_hz"):
        estimate_joints(ch.points(), ch.groups, specs, cutoff_hz=6.0)


# ------------------------------------------------------------------ the human model
@pytest.fixture(scope="module")
def squats(human):
    """A 500-frame squat trial at 1 mm noise, its estimate and the true hinge axes per frame."""
    sim = simulate_squats(human, frames=500, noise_mm=1.0, seed=1)
    est = estimate_model_joints(human, sim.trial)
    return sim, est, joint_axes_world(human, sim.truth, sim.motion)


def test_every_human_joint_gets_a_trajectory(human, squats):
    sim, est, _ = squats
    assert est.names == tuple(j.name for j in human.joints)
    for j in est:
        assert j.ok, (j.name, j.reason)
        assert j.frames == sim.trial.n_frames
        assert np.isfinite(j.centre).all()
    talus = [j for j in est if "talus" in j.note]
    assert {j.name for j in talus} == {"ankle_l", "ankle_r", "subtalar_l", "subtalar_r"}


def test_human_hip_knee_elbow_accuracy(human, squats):
    """Issue 3 item 9: hips ≤ 5 mm (median), knee/elbow centres ≤ 5 mm from the true axis, axes ≤ 3°."""
    sim, est, axes = squats
    for side in "lr":
        k = human.joint_index(f"hip_{side}")
        err = np.linalg.norm(est[f"hip_{side}"].centre - sim.clean_centres[:, k], axis=1)
        assert np.median(err) < 0.005
        for name in (f"knee_{side}", f"elbow_{side}"):
            e = est[name]
            assert e.kind == "hinge" and e.axis is not None
            ax = axes[name]
            v = e.centre - sim.clean_centres[:, human.joint_index(name)]
            off_axis = np.linalg.norm(v - np.sum(v * ax, axis=1)[:, None] * ax, axis=1)
            assert np.median(off_axis) < 0.005, name
            angle = np.degrees(np.arccos(np.clip(np.abs(np.sum(e.axis * ax, axis=1)), 0, 1)))
            assert np.median(angle) < 3.0, name
            assert np.allclose(np.linalg.norm(e.axis, axis=1), 1.0)


def test_human_ball_joint_accuracy(human, squats):
    """Centres of the ball joints against the simulator's truth (medians over frames, today):
    lumbar 0.51, neck 0.28, shoulders 0.63 / 0.37, wrists 0.40 / 1.31 mm.  3 mm, about 2x the worst
    of them: a regression of 2-3x fails, and so does a centre off by a marker's offset (1 cm)."""
    sim, est, axes = squats
    for name in ("lumbar", "neck", "shoulder_l", "shoulder_r", "wrist_l", "wrist_r"):
        err = np.linalg.norm(est[name].centre - sim.clean_centres[:, human.joint_index(name)], axis=1)
        assert np.median(err) < 0.003, (name, np.median(err))
    # Ankles: the talus carries no markers, so the ankle is found as the centre of rotation of the
    # calcaneus against the tibia, through the talocrural and subtalar hinges together.  Their axes
    # pass within 2-6 mm of each other, so that point lies on the true talocrural axis (0.57 mm left,
    # 1.69 mm right, today) but anywhere along it (14.8 mm left, 8.0 mm right from the true centre).
    # Expected: within 4 mm of the axis (a centre off the axis fails), and within 25 mm of the true
    # centre (along the axis: less than a third of the ankle-subtalar distance, 58-82 mm).
    for name in ("ankle_l", "ankle_r"):
        v = est[name].centre - sim.clean_centres[:, human.joint_index(name)]
        ax = axes[name]
        off_axis = np.linalg.norm(v - np.sum(v * ax, axis=1)[:, None] * ax, axis=1)
        assert np.median(off_axis) < 0.004, (name, np.median(off_axis))
        assert np.median(np.linalg.norm(v, axis=1)) < 0.025, name


def test_human_with_gaps(human):
    sim = simulate_squats(human, frames=300, noise_mm=1.0, gaps=True, seed=2)
    est = estimate_model_joints(human, sim.trial)
    assert all(j.ok for j in est)
    k = human.joint_index("hip_r")
    err = np.linalg.norm(est["hip_r"].centre - sim.clean_centres[:, k], axis=1)
    assert np.nanmedian(err) < 0.005
    # frames where no femur/pelvis frame can be formed are NaN, never garbage: the worst frame is
    # 2.0 mm off (median 1.2 mm).  5 mm: a frame formed from too few markers, or a gap filled with
    # a stale position, is a marker offset (cm) off.
    assert np.nanmax(err) < 0.005


def test_missing_segment_markers_are_reported(human):
    """A joint whose one side carries no marker the trial shows (the left foot without its heel and toe; a
    lower-body trial's trunk, head and arms) is not estimated: per-frame JMV there would fit the other side's points
    and the joint estimates made from them, which turn with it.  The joints between seen segments are."""
    sim = simulate_squats(human, frames=200, noise_mm=1.0, seed=3)
    keep = [lab for lab in sim.trial.labels if lab not in ("LHEE", "LTOE")]
    trial = sim.trial.select(keep)
    est = estimate_model_joints(human, trial)
    sub = est["subtalar_l"]
    assert not sub.ok and sub.method == "failed"
    assert sub.reason == "no marker the trial shows moves with calcn_l (nor beyond it)"
    assert est["hip_l"].ok and est["knee_l"].ok
    legs = {mk.name for mk in human.markers if human.segment_index(mk.segment) < human.segment_index("torso")}
    lower = estimate_model_joints(human, sim.trial.select([lab for lab in sim.trial.labels if lab in legs]))
    upper = [j.name for j in human.joints if j.name.startswith(("lumbar", "neck", "shoulder", "elbow", "wrist"))]
    assert upper and all(not lower[j].ok for j in upper)
    assert lower["lumbar"].reason == "no marker the trial shows moves with torso (nor beyond it)"
    assert all(lower[j].ok for j in ("hip_l", "hip_r", "knee_l", "knee_r"))


# ------------------------------------------------------------------ CLI
def test_cli_joints_prints_table_and_writes_csv(human, tmp_path, capsys):
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=4)
    paths = write_simulation(sim, tmp_path)
    out = tmp_path / "centres.csv"
    code = main(["joints", str(paths["trial"]), str(human.path), "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    assert "knee_r" in text and "MTB" in text and "18/18 joints estimated" in text
    rows = list(csv.reader(out.open()))
    header, body = rows[0], np.array(rows[1:], dtype=float)
    assert body.shape[0] == 300
    est = estimate_model_joints(human, Trial(sim.trial.labels, sim.trial.markers, sim.trial.rate, 0, None))
    col = header.index("hip_r_x")
    assert np.max(np.abs(body[:, col:col + 3] - est["hip_r"].centre)) < 2e-6  # written with 1 µm resolution
    assert "knee_r_axis_x" in header
    # no overwrite without --overwrite; one clear line, exit 2
    code = main(["joints", str(paths["trial"]), str(human.path), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "already exists" in err and err.count("\n") == 1
    # a knee label exchanged with the ankle's for the whole trial: named, with the exchange that explains it
    from calibrate.io.c3d import write_c3d

    labels = list(sim.trial.labels)
    i, j = labels.index("RKNE"), labels.index("RANK")
    labels[i], labels[j] = labels[j], labels[i]
    write_c3d(tmp_path / "swapped.c3d", Trial(labels, sim.trial.markers, sim.trial.rate, 0, None))
    main(["joints", str(tmp_path / "swapped.c3d"), str(human.path)])
    err = capsys.readouterr().err
    assert "warning: RKNE moves with" in err and "RKNE and RANK" in err
    # two labels of one segment exchanged: against the base model's distances
    labels = list(sim.trial.labels)
    i, j = labels.index("LKNE"), labels.index("LTHI")
    labels[i], labels[j] = labels[j], labels[i]
    write_c3d(tmp_path / "within.c3d", Trial(labels, sim.trial.markers, sim.trial.rate, 0, None))
    main(["joints", str(tmp_path / "within.c3d"), str(human.path), "--out", str(tmp_path / "within")])
    err = capsys.readouterr().err
    assert "warning: LKNE and LTHI (both on femur_l) sit each where the other belongs in within.c3d" in err


def test_cli_joints_bad_input(human, tmp_path, capsys):
    sim = simulate_squats(human, frames=50, noise_mm=1.0, seed=5)
    paths = write_simulation(sim, tmp_path)
    renamed = Trial(tuple(f"X{i}" for i in range(sim.trial.n_markers)), sim.trial.markers, 100.0, 0, None)
    from calibrate.io.c3d import write_c3d

    write_c3d(tmp_path / "renamed.c3d", renamed)
    code = main(["joints", str(tmp_path / "renamed.c3d"), str(human.path)])
    err = capsys.readouterr().err
    assert code == 2 and "none of its 39 labels" in err
    code = main(["joints", str(paths["trial"]), str(tmp_path / "missing.urdf")])
    assert code == 2 and "missing.urdf" in capsys.readouterr().err


def test_cli_joints_places_markers_the_model_does_not_know(human, tmp_path, capsys):
    """An extra marker rigid with the right shank is placed on tibia_r by rigidity and used."""
    sim = simulate_squats(human, frames=300, noise_mm=1.0, seed=6)
    i, k = human.marker_index("RTIB"), human.marker_index("RANK")
    shin = sim.clean_markers[:, i] + 0.4 * (sim.clean_markers[:, k] - sim.clean_markers[:, i])
    shin = shin + np.random.default_rng(0).normal(0, 1e-3, shin.shape)
    markers = np.concatenate([sim.trial.markers, shin[:, None, :]], axis=1)
    trial = Trial((*sim.trial.labels, "RSHIN"), markers, sim.trial.rate, 0, None)
    from calibrate.io.c3d import write_c3d

    write_c3d(tmp_path / "extra.c3d", trial)
    code = main(["joints", str(tmp_path / "extra.c3d"), str(human.path)])
    out = capsys.readouterr().out
    assert code == 0
    line = next(ln for ln in out.splitlines() if ln.strip().startswith("RSHIN"))
    assert "-> tibia_r" in line
    with_extra = estimate_model_joints(human, trial, extra_markers={"RSHIN": "tibia_r"})
    assert with_extra["ankle_r"].ok
    # The talus carries no markers: the 'ankle' is found against the calcaneus, a point on the true
    # talocrural axis (1.8 mm from it today, 2.0 with RSHIN) whose place along the axis the data do
    # not fix (6.6 mm from the true centre).  4 mm from the axis: a centre off the axis fails.
    k = human.joint_index("ankle_r")
    ax = joint_axes_world(human, sim.truth, sim.motion)["ankle_r"]
    v = with_extra["ankle_r"].centre - sim.clean_centres[:, k]
    assert np.median(np.linalg.norm(v - np.sum(v * ax, axis=1)[:, None] * ax, axis=1)) < 0.004
    with pytest.raises(ValueError, match="not a segment"):
        estimate_model_joints(human, trial, extra_markers={"RSHIN": "shin"})


def test_a_joint_whose_points_no_frame_shows_is_refused_before_the_jmv_search(human, monkeypatch):
    """A lower-body trial that keeps the torso's and head's labels with no position in any frame (BTKData's
    FunctionalWalk): the neck has 11 points around it, none seen, and is refused as having no marker the trial shows
    on its side, without the JMV multistart's grid search (0.4 s there for a seed refused anyway); the legs' joints are
    estimated as before (the hips within 10 mm of the truth; 2.6 and 6.6 mm today)."""
    import calibrate.seed.joints as joints

    sim = simulate_squats(human, frames=120, noise_mm=1.0, seed=4)
    upper = [k for k, lab in enumerate(sim.trial.labels)
             if lab in human.segments[human.segment_index("torso")].markers
             or lab in human.segments[human.segment_index("head")].markers]
    X = sim.trial.markers.copy()
    X[:, upper] = np.nan
    trial = Trial(sim.trial.labels, X, sim.trial.rate)
    searched: list[int] = []  # the points each multistart searched around, seen in any frame

    def counting(X, *args, **kwargs):
        searched.append(int(np.isfinite(X).all(axis=2).any(axis=0).sum()))
        return jmv_multistart(X, *args, **kwargs)

    from calibrate.seed.mtb import jmv_multistart
    monkeypatch.setattr(joints, "jmv_multistart", counting)
    est = estimate_model_joints(human, trial)
    neck = est["neck"]
    assert not neck.ok and neck.reason == "no marker the trial shows moves with torso (nor beyond it)", neck.reason
    assert 0 not in searched  # no search around points no frame shows
    for name in ("hip_l", "hip_r"):  # the legs' joints found from their own markers
        err = np.linalg.norm(est[name].centre - sim.clean_centres[:, human.joint_index(name)], axis=1)
        assert est[name].ok and np.median(err) < 0.010, (name, np.median(err))
