"""Synthetic cameras for a simulated trial: a ring of calibrated cameras around the capture volume and
the unlabelled 2-D detections they would make of the markers (seed 002's input).

Cameras: N (default 8) on a circle of radius 4.5 m, 2.4-2.8 m high, looking at a point 1 m above the
centre; 2048 × 2048 px sensors with a 1500-1700 px focal length (about 65° field of view, as a
motion-capture camera with a wide lens), principal point within 10 px of the centre, slight barrel
distortion.  Detections: every marker in front of a camera and on its image, unless the body hides it —
the body is a capsule (radius 5.5 cm, 3.5 cm on the forearms, hands and feet segments, 10 cm on the
pelvis and torso) around every segment from its joint centre to the next — then Gaussian noise
(0.3 px), missed detections (1 %) and false detections (Poisson, 0.5 per camera and frame, uniform on
the image).  The truth: which marker (or -1, false) made every detection.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.cameras import Camera, Detections, look_at, write_camera_files
from ..model.model import Model

RADIUS = 4.5  # m: cameras' distance from the centre of the volume


@dataclass(frozen=True)
class CameraSimulation:
    """Cameras, their detections and the truth of every detection."""

    cameras: list[Camera]
    detections: Detections
    marker: np.ndarray  # (n,) marker index of every detection row, -1 for a false detection


def ring_cameras(n: int = 8, seed: int = 0, radius: float = RADIUS) -> list[Camera]:
    """`n` cameras evenly around the volume (module docstring), each slightly different."""
    if n < 2:
        raise ValueError(f"cameras: need at least 2, got {n}")
    rng = np.random.default_rng([seed, 7])
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + rng.uniform(-0.1, 0.1)
        h = rng.uniform(2.4, 2.8)
        f = rng.uniform(1500, 1700)
        K = np.array([[f, 0, 1024 + rng.uniform(-10, 10)], [0, f, 1024 + rng.uniform(-10, 10)], [0, 0, 1]])
        dist = (rng.uniform(-0.05, -0.01), rng.uniform(0.0, 0.01), 0.0, 0.0, 0.0)
        cams.append(look_at(f"cam{i + 1}", (radius * np.cos(a), radius * np.sin(a), h), (0.0, 0.0, 1.0), K,
                            (2048, 2048), dist))
    return cams


def body_capsules(model: Model, centres: np.ndarray, markers: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                                     np.ndarray]:
    """Capsules approximating the body in every frame: ends (F, S, 3) and (F, S, 3), radii (S,).  One per
    joint from its centre to the next joint of its child segment, or to the mean of the child's markers."""
    names = [j.name for j in model.joints]
    a_idx, b_pts, radii = [], [], []
    for j, joint in enumerate(model.joints):
        kids = [i for i, other in enumerate(model.joints) if other.parent == joint.child]
        seg = joint.child.lower()
        r = 0.10 if any(s in seg for s in ("torso", "pelvis", "trunk", "thorax", "lumbar", "back")) else (
            0.035 if any(s in seg for s in ("radius", "ulna", "hand", "calcn", "toes", "forearm", "foot")) else 0.055)
        ends = [("joint", i) for i in kids] or [("markers", joint.child)]
        for kind, what in ends:
            a_idx.append(j)
            if kind == "joint":
                b_pts.append(centres[:, what])
            else:
                mk = [i for i, m in enumerate(model.markers) if m.segment == what]
                b_pts.append(np.nanmean(markers[:, mk], axis=1) if mk else centres[:, j])
            radii.append(r)
    del names
    a, b = centres[:, a_idx], np.stack(b_pts, axis=1)
    # no marker inside a capsule: each radius at most 80 % of the nearest marker's distance from its axis
    near = _segment_distance(markers[:, :, None], markers[:, :, None], a[:, None], b[:, None])
    near = np.nanmin(np.nanmedian(near, axis=0), axis=0)
    return a, b, np.minimum(np.array(radii), 0.8 * near)


def _segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Shortest distances between segments p0-p1 (..., 3) and q0-q1 (..., 3), broadcast."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.sum(d1 * d1, -1)
    e = np.sum(d2 * d2, -1)
    f = np.sum(d2 * r, -1)
    c = np.sum(d1 * r, -1)
    b = np.sum(d1 * d2, -1)
    den = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip(np.where(den > 1e-12, (b * f - c * e) / den, 0.0), 0, 1)
        t = np.where(e > 1e-12, (b * s + f) / e, 0.0)
        t_c = np.clip(t, 0, 1)
        s = np.where(t != t_c, np.clip(np.where(a > 1e-12, (b * t_c - c) / a, 0.0), 0, 1), s)
    return np.linalg.norm(p0 + d1 * s[..., None] - (q0 + d2 * t_c[..., None]), axis=-1)


def detect(cameras: list[Camera], markers: np.ndarray, capsules, rate: float, seed: int = 0,
           noise_px: float = 0.3, miss: float = 0.01, false_rate: float = 0.5) -> CameraSimulation:
    """The detections (module docstring) of marker trajectories (F, N, 3) (NaN: not there) by `cameras`."""
    rng = np.random.default_rng([seed, 11])
    F, N, _ = markers.shape
    a, b, radii = capsules
    frames, cams, uvs, truth = [], [], [], []
    for m, cam in enumerate(cameras):
        uv, z = cam.project(markers)
        ok = np.isfinite(uv[..., 0]) & (z > 0.1) & cam.inside(uv)
        c = cam.centre
        # a ray from the camera to the marker, stopped 1.5 cm short of it, must clear every capsule
        end = markers - 0.015 * (markers - c) / np.linalg.norm(markers - c, axis=-1, keepdims=True)
        for f0 in range(0, F, 100):
            sl = slice(f0, min(F, f0 + 100))
            dd = _segment_distance(c[None, None, None], end[sl, :, None], a[sl, None], b[sl, None])
            ok[sl] &= ~np.any(dd < radii[None, None, :], axis=2)
        ok &= rng.random(ok.shape) >= miss
        f_idx, n_idx = np.nonzero(ok)
        frames.append(f_idx)
        cams.append(np.full(f_idx.size, m))
        uvs.append(uv[f_idx, n_idx] + rng.normal(0, noise_px, (f_idx.size, 2)))
        truth.append(n_idx)
        nf = rng.poisson(false_rate, F)
        ff = np.repeat(np.arange(F), nf)
        frames.append(ff)
        cams.append(np.full(ff.size, m))
        uvs.append(rng.uniform([0, 0], [cam.size[0] - 1, cam.size[1] - 1], (ff.size, 2)))
        truth.append(np.full(ff.size, -1))
    frame, camera, uv, mk = (np.concatenate(x) for x in (frames, cams, uvs, truth))
    shuffle = rng.permutation(frame.size)  # no order within a frame and camera
    frame, camera, uv, mk = frame[shuffle], camera[shuffle], uv[shuffle], mk[shuffle]
    det = Detections(frame.astype(np.int64), camera.astype(np.int64), uv, float(rate), F, len(cameras))
    order = np.lexsort((camera, frame))  # the order Detections keeps
    return CameraSimulation(list(cameras), det, mk[order])


def simulate_cameras(sim, n_cameras: int = 8, seed: int = 0, noise_px: float = 0.3, miss: float = 0.01,
                     false_rate: float = 0.5) -> CameraSimulation:
    """Cameras and detections of a calibrate.simulation Simulation's markers (its skin markers before noise
    and gaps: the bone model's plus any soft-tissue artefact)."""
    markers = sim.clean_markers if sim.artefact is None else sim.clean_markers + sim.artefact
    cams = ring_cameras(n_cameras, seed)
    caps = body_capsules(sim.model, sim.clean_centres, markers)
    return detect(cams, markers, caps, sim.trial.rate, seed, noise_px, miss, false_rate)


def camera_paths(out: Path) -> dict[str, Path]:
    """Where write_camera_simulation puts its files in `out`."""
    return {"cameras": out / "cameras.toml", "detections": out / "detections.npz",
            "truth_detections": out / "truth_detections.npz"}


def write_camera_simulation(cs: CameraSimulation, out: Path, markers: np.ndarray) -> dict[str, Path]:
    """Write cameras.toml, detections.npz and truth_detections.npz (`marker` of every detection row, and the
    true marker trajectories `markers` (F, N, 3) m) into `out`, all or none."""
    paths = camera_paths(Path(out))
    write_camera_files(paths["cameras"], cs.cameras, paths["detections"], cs.detections,
                       {paths["truth_detections"]: {"marker": cs.marker, "markers": markers}})
    return paths
