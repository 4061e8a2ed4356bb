"""The synthetic chain simulator: geometry and motion checked from the trajectories themselves."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.seed.geometry import rigid_fit, sphere_fit, spread
from calibrate.simulation.chains import Chain, simulate_chain

CHAINS = [(4, 3, 3), (4, 3, 3, 4, 3), (4, 3, 3, 4, 3, 3, 3, 3), (3, 2, 2, 2, 2), (3, 1, 2, 2, 2, 2)]


def columns(chain: Chain, segment: str) -> list[int]:
    """Marker indices of a segment."""
    return [chain.labels.index(lab) for lab in chain.groups[segment]]


def test_shapes_labels_groups_joints():
    ch = simulate_chain([3, 1, 2], frames=37, seed=1)
    assert ch.markers.shape == ch.clean_markers.shape == (37, 6, 3)
    assert ch.centres.shape == (37, 2, 3)
    assert ch.labels == ("s0m0", "s0m1", "s0m2", "s1m0", "s2m0", "s2m1")
    assert ch.groups == {"s0": ("s0m0", "s0m1", "s0m2"), "s1": ("s1m0",), "s2": ("s2m0", "s2m1")}
    assert ch.segments == ("s0", "s1", "s2")
    assert ch.joints == (("j0", "s0", "s1"), ("j1", "s1", "s2"))
    pts = ch.points()
    assert list(pts) == list(ch.labels)
    for k, lab in enumerate(ch.labels):
        assert pts[lab].shape == (37, 3)
        np.testing.assert_array_equal(pts[lab], ch.markers[:, k])
    pts["s0m0"][:] = 0.0  # a copy: the chain is untouched
    assert np.all(ch.markers[:, 0] != 0.0)
    assert np.all(np.isfinite(ch.markers))


@pytest.mark.parametrize("counts", CHAINS)
def test_joints_one_apart_and_end_segments_length_one(counts):
    ch = simulate_chain(counts, frames=120, seed=3)
    gaps = np.linalg.norm(np.diff(ch.centres, axis=1), axis=2)
    np.testing.assert_allclose(gaps, 1.0, rtol=0, atol=1e-12)
    # the free end of the first segment is 1 from j0; the frames' x axes run along the segments
    np.testing.assert_allclose(np.linalg.norm(ch.centres[:, 0] - ch.origins[:, 0], axis=1), 1.0, atol=1e-12)
    tip = ch.origins[:, -1] + ch.rotations[:, -1, :, 0]
    np.testing.assert_allclose(np.linalg.norm(tip - ch.centres[:, -1], axis=1), 1.0, atol=1e-12)


@pytest.mark.parametrize("counts", CHAINS)
def test_markers_rigid_on_their_segment(counts):
    ch = simulate_chain(counts, frames=100, seed=5)
    L = len(counts)
    for i in range(L):
        cols = columns(ch, f"s{i}")
        own = ([i - 1] if i > 0 else []) + ([i] if i < L - 1 else [])
        for j in own:  # marker-to-joint distances constant over frames
            d = np.linalg.norm(ch.clean_markers[:, cols] - ch.centres[:, j, None], axis=2)
            np.testing.assert_allclose(d - d[0], 0.0, atol=1e-12)
            assert d.min() > 0.09  # markers sit 0.1-0.4 off the segment axis
        if len(cols) > 1:  # inter-marker distances constant
            p = ch.clean_markers[:, cols]
            d = np.linalg.norm(p[:, :, None] - p[:, None], axis=3)
            np.testing.assert_allclose(d - d[0], 0.0, atol=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_marker_groups_in_general_position(seed):
    ch = simulate_chain((4, 3, 3, 4, 3, 2, 1), seed=seed)
    for seg in ch.segments:
        p = ch.clean_markers[0, columns(ch, seg)]
        s2, s3 = spread(p)
        if len(p) >= 3:
            assert s2 >= 0.1, (seg, s2)  # non-collinear
        if len(p) >= 4:
            assert s3 >= 0.1, (seg, s3)  # non-coplanar


@pytest.mark.parametrize("seed", range(5))
def test_relative_rotation_is_a_ball_joint_not_a_hinge(seed):
    """The child's markers, in the parent's frame (from the parent's markers), move about a fixed
    point (the true centre) but not about one fixed axis."""
    counts = (4, 3, 3, 4, 3)
    ch = simulate_chain(counts, frames=100, seed=seed)
    ratios = []
    for i in range(len(counts) - 1):
        parent = rigid_fit(ch.clean_markers[:, columns(ch, f"s{i}")])
        child = parent.to_local(ch.clean_markers[:, columns(ch, f"s{i + 1}")])
        centre = parent.to_local(ch.centres[:, i])
        np.testing.assert_allclose(centre - centre[0], 0.0, atol=1e-9)  # the joint is fixed on the parent
        fit = sphere_fit(child)
        np.testing.assert_allclose(fit.centre, centre[0], atol=1e-8)  # and is the centre of rotation
        assert fit.hinge_ratio > 0.02, (i, fit.hinge_ratio)
        ratios.append(fit.hinge_ratio)
    assert np.median(ratios) > 0.05


def test_hinge_ratio_detects_a_hinge():
    """Control for the test above: rotation about one fixed axis gives a near-zero hinge ratio."""
    rng = np.random.default_rng(0)
    angles = np.linspace(0.0, 1.5, 100)
    rot = Rotation.from_rotvec(angles[:, None] * np.array([0.0, 0.6, 0.8]))
    pts = np.stack([rot.apply(p) for p in rng.uniform(-1, 1, (3, 3))], axis=1)
    assert sphere_fit(pts).hinge_ratio < 1e-10


def test_rotation_magnitude_of_order_one_to_two_radians():
    excursions = []
    for seed in range(10):
        ch = simulate_chain((4, 3, 3, 4, 3), frames=100, seed=seed)
        R = ch.rotations
        for i in range(R.shape[1] - 1):
            rel = np.einsum("fji,fjk->fik", R[:, i], R[:, i + 1])  # child in parent frame
            excursions.append(Rotation.from_matrix(np.einsum("ji,fjk->fik", rel[0], rel)).magnitude().max())
    assert 0.8 < np.median(excursions) < 2.5
    assert min(excursions) > 0.3


@pytest.mark.parametrize("noise", [0.001, 0.01])
def test_noise_std(noise):
    ch = simulate_chain((4, 3, 3, 4, 3), frames=100, noise=noise, seed=7)
    e = ch.markers - ch.clean_markers
    assert abs(e.std() / noise - 1.0) < 0.1
    assert abs(e.mean()) < 0.1 * noise
    assert abs(e.reshape(-1, 3).std(0) / noise - 1.0).max() < 0.1  # isotropic
    quiet = simulate_chain((4, 3, 3, 4, 3), frames=100, noise=0.0, seed=7)
    np.testing.assert_array_equal(quiet.markers, quiet.clean_markers)
    np.testing.assert_array_equal(quiet.clean_markers, ch.clean_markers)  # noise is drawn last


def test_seed_reproducibility():
    a = simulate_chain((3, 2, 2), noise=0.001, seed=11)
    b = simulate_chain((3, 2, 2), noise=0.001, seed=11)
    c = simulate_chain((3, 2, 2), noise=0.001, seed=12)
    np.testing.assert_array_equal(a.markers, b.markers)
    np.testing.assert_array_equal(a.centres, b.centres)
    assert not np.allclose(a.clean_markers, c.clean_markers)
    g1 = simulate_chain((3, 2, 2), seed=np.random.default_rng(4))
    g2 = simulate_chain((3, 2, 2), seed=np.random.default_rng(4))
    np.testing.assert_array_equal(g1.markers, g2.markers)
    # the geometry does not depend on the number of frames
    long = simulate_chain((3, 2, 2), frames=300, seed=11)
    np.testing.assert_array_equal(long.local, a.local)
    np.testing.assert_allclose(long.centres[0], a.centres[0], atol=1e-12)


def test_bad_arguments():
    with pytest.raises(ValueError):
        simulate_chain([])
    with pytest.raises(ValueError):
        simulate_chain([3, 0, 2])
    with pytest.raises(ValueError):
        simulate_chain([3, 2], frames=1)
    with pytest.raises(ValueError):
        simulate_chain([3, 2], noise=-1.0)
