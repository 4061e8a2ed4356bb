"""Camera calibrations and unlabelled 2-D detections: the input of seed 002's 3-D tracker.

Conventions are OpenCV's (docs/tracking.md):

* a world point X (m) is seen in camera coordinates as ``x = R X + t`` (R: world-to-camera
  rotation, t in metres), the camera looking along its +z axis, x to the right, y down;
* normalised coordinates (a, b) = (x/z, y/z) are distorted by the Brown–Conrady model with
  coefficients (k1, k2, p1, p2, k3) and mapped to pixels by K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]];
  pixel (0, 0) is the centre of the top-left pixel.

Calibration file (TOML, or JSON with the same structure)::

    [[camera]]
    name = "cam1"
    size = [2048, 2048]                   # width, height (px)
    K = [[1600, 0, 1024], [0, 1600, 1024], [0, 0, 1]]
    dist = [-0.02, 0.0, 0.0, 0.0, 0.0]    # optional: k1, k2, p1, p2, k3 (fewer: the rest 0)
    R = [[...], [...], [...]]             # or rvec = [rx, ry, rz] (Rodrigues, as cv2.Rodrigues)
    t = [0.1, -0.2, 4.5]                  # m

Detections file (NPZ): ``frame`` (n,) int, ``camera`` (n,) int (0-based, order of the calibration
file), ``uv`` (n, 2) float pixels, ``rate`` () float Hz, ``n_frames`` () int; the detections of a
frame and camera in no particular order, unlabelled.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomllib

from ..errors import CalibrateError
from ..model.rotations import rotvec_matrices
from .outputs import put_text, write_all


class CameraError(CalibrateError):
    """A camera calibration or detections file that cannot be used."""


@dataclass(frozen=True)
class Camera:
    """One calibrated camera (OpenCV's pinhole model with Brown–Conrady distortion)."""

    name: str
    K: np.ndarray  # (3, 3) intrinsics, pixels
    dist: np.ndarray  # (5,) k1, k2, p1, p2, k3
    R: np.ndarray  # (3, 3) world-to-camera rotation
    t: np.ndarray  # (3,) m: x_cam = R X + t
    size: tuple[int, int]  # width, height (px)

    @property
    def centre(self) -> np.ndarray:
        """The optical centre in the world (m): -Rᵀ t."""
        return -self.R.T @ self.t

    @property
    def focal(self) -> float:
        """Mean focal length (px)."""
        return 0.5 * float(self.K[0, 0] + self.K[1, 1])

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """World points (..., 3) in camera coordinates."""
        return X @ self.R.T + self.t

    def distort(self, ab: np.ndarray) -> np.ndarray:
        """Normalised coordinates (..., 2) -> pixels (..., 2)."""
        k1, k2, p1, p2, k3 = self.dist
        a, b = ab[..., 0], ab[..., 1]
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        ad = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
        bd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
        K = self.K
        return np.stack([K[0, 0] * ad + K[0, 1] * bd + K[0, 2], K[1, 1] * bd + K[1, 2]], axis=-1)

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (..., 2) of world points (..., 3) and their depths (..., ) (<= 0: behind the camera)."""
        xc = self.to_camera(X)
        z = xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            ab = xc[..., :2] / z[..., None]
        return self.distort(ab), z

    def normalise(self, uv: np.ndarray, iterations: int = 8) -> np.ndarray:
        """Pixels (..., 2) -> undistorted normalised coordinates (..., 2) (fixed-point iteration, as
        cv2.undistortPoints)."""
        K = self.K
        bd = (uv[..., 1] - K[1, 2]) / K[1, 1]
        ad = (uv[..., 0] - K[0, 2] - K[0, 1] * bd) / K[0, 0]
        k1, k2, p1, p2, k3 = self.dist
        if not np.any(self.dist):
            return np.stack([ad, bd], axis=-1)
        a, b = ad.copy(), bd.copy()
        for _ in range(iterations):
            r2 = a * a + b * b
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            da = 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
            db = p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
            a = (ad - da) / radial
            b = (bd - db) / radial
        return np.stack([a, b], axis=-1)

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit world directions (..., 3) of the rays through pixels (..., 2) from the optical centre."""
        ab = self.normalise(uv)
        d = np.concatenate([ab, np.ones(ab.shape[:-1] + (1,))], axis=-1) @ self.R  # Rᵀ d_cam
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def inside(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixels (..., 2) fall on the image."""
        w, h = self.size
        return (uv[..., 0] >= -0.5) & (uv[..., 0] <= w - 0.5) & (uv[..., 1] >= -0.5) & (uv[..., 1] <= h - 0.5)


def look_at(name: str, centre: Sequence[float], target: Sequence[float], K: np.ndarray, size: tuple[int, int],
            dist: Sequence[float] = (0.0, 0.0, 0.0, 0.0, 0.0)) -> Camera:
    """A camera at `centre` (m) looking at `target`, the world's +z up in the image."""
    c, g = np.asarray(centre, float), np.asarray(target, float)
    z = g - c
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image y runs down: world up is -y
    R = np.vstack([x, y, z])
    return Camera(name, np.asarray(K, float), np.asarray(dist, float), R, -R @ c, (int(size[0]), int(size[1])))


# ---------------------------------------------------------------------------------------------- files


def _matrix(path: Path, name: str, key: str, value, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != shape or not np.all(np.isfinite(a)):
        raise CameraError(f"{path}: camera '{name}': '{key}' must be {'x'.join(map(str, shape))} finite numbers; "
                          "fix the calibration file (docs/tracking.md)")
    return a


def _camera(path: Path, i: int, entry) -> Camera:
    if not isinstance(entry, dict):
        raise CameraError(f"{path}: camera {i + 1} is not a table; write each camera as [[camera]] with K, R, t, size")
    name = str(entry.get("name", f"cam{i + 1}"))
    for key in ("K", "t", "size"):
        if key not in entry:
            raise CameraError(f"{path}: camera '{name}' has no '{key}'; add it (docs/tracking.md)")
    K = _matrix(path, name, "K", entry["K"], (3, 3))
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise CameraError(f"{path}: camera '{name}': K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    dist = np.zeros(5)
    if "dist" in entry:
        d = np.atleast_1d(np.asarray(entry["dist"], dtype=float)) if isinstance(entry["dist"], list) else None
        if d is None or d.ndim != 1 or not 0 < d.size <= 5 or not np.all(np.isfinite(d)):
            raise CameraError(f"{path}: camera '{name}': 'dist' must be 1-5 numbers k1, k2, p1, p2, k3")
        dist[:d.size] = d
    if ("R" in entry) == ("rvec" in entry):
        raise CameraError(f"{path}: camera '{name}': give the rotation as exactly one of 'R' (3x3) or 'rvec' (3)")
    if "R" in entry:
        R = _matrix(path, name, "R", entry["R"], (3, 3))
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise CameraError(f"{path}: camera '{name}': 'R' is not a rotation matrix (orthonormal, det +1)")
    else:
        R = rotvec_matrices(_matrix(path, name, "rvec", entry["rvec"], (3,)))
    t = _matrix(path, name, "t", entry["t"], (3,))
    size = _matrix(path, name, "size", entry["size"], (2,))
    if np.any(size < 1) or np.any(size != np.round(size)):
        raise CameraError(f"{path}: camera '{name}': 'size' must be two whole numbers of pixels, width and height")
    return Camera(name, K, dist, R, t, (int(size[0]), int(size[1])))


def read_cameras(path: str | Path) -> list[Camera]:
    """The cameras of a calibration file (.toml or .json; module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise CameraError(f"{path}: no such file; give the camera calibration (.toml or .json)")
    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (OSError, UnicodeDecodeError) as e:
        raise CameraError(f"{path}: cannot read ({e}); give the camera calibration as a text file") from None
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as e:
        kind = path.suffix.lstrip(".").upper() or "TOML"
        raise CameraError(f"{path}: not valid {kind} ({e}); fix the file") from None
    cams = data.get("camera") if isinstance(data, dict) else None
    if not isinstance(cams, list) or not cams:
        raise CameraError(f"{path}: no cameras; list them as [[camera]] tables (JSON: \"camera\": [...])")
    out = [_camera(path, i, c) for i, c in enumerate(cams)]
    names = [c.name for c in out]
    if len(set(names)) < len(names):
        raise CameraError(f"{path}: two cameras share a name; give each its own")
    return out


def _row(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in np.ravel(v)) + "]"


def cameras_toml(cameras: Sequence[Camera]) -> str:
    """The calibration file's text for `cameras` (TOML; read back by read_cameras)."""
    lines = ["# camera calibration: OpenCV conventions (x_cam = R X + t, metres; K in pixels; docs/tracking.md)"]
    for c in cameras:
        lines += ["", "[[camera]]", f"name = {json.dumps(c.name)}", f"size = [{c.size[0]}, {c.size[1]}]",
                  "K = [" + ", ".join(_row(r) for r in c.K) + "]", f"dist = {_row(c.dist)}",
                  "R = [" + ", ".join(_row(r) for r in c.R) + "]", f"t = {_row(c.t)}"]
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class Detections:
    """Unlabelled 2-D detections: every bright point of every camera in every frame."""

    frame: np.ndarray  # (n,) int
    camera: np.ndarray  # (n,) int, 0-based
    uv: np.ndarray  # (n, 2) pixels
    rate: float  # Hz
    n_frames: int
    n_cameras: int

    def __post_init__(self) -> None:
        order = np.lexsort((self.camera, self.frame))
        for k in ("frame", "camera", "uv"):
            object.__setattr__(self, k, np.asarray(getattr(self, k))[order])
        key = self.frame.astype(np.int64) * self.n_cameras + self.camera
        bounds = np.searchsorted(key, np.arange(self.n_frames * self.n_cameras + 1))
        object.__setattr__(self, "_bounds", bounds)

    def span(self, frame: int, camera: int) -> slice:
        """Rows of the detections of one frame and camera."""
        k = frame * self.n_cameras + camera
        b = self._bounds  # type: ignore[attr-defined]
        return slice(int(b[k]), int(b[k + 1]))

    def at(self, frame: int, camera: int) -> np.ndarray:
        """(q, 2) pixels of one frame and camera."""
        return self.uv[self.span(frame, camera)]

    def arrays(self) -> dict[str, np.ndarray]:
        """The NPZ file's arrays."""
        return {"frame": self.frame, "camera": self.camera, "uv": self.uv, "rate": np.array(self.rate),
                "n_frames": np.array(self.n_frames), "n_cameras": np.array(self.n_cameras)}


def read_detections(path: str | Path, n_cameras: int | None = None) -> Detections:
    """The detections of an NPZ file (module docstring); `n_cameras`: the calibration's, checked."""
    path = Path(path)
    if not path.is_file():
        raise CameraError(f"{path}: no such file; give the detections (.npz)")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as e:  # noqa: BLE001 - any unreadable archive is one line
        raise CameraError(f"{path}: not a readable NPZ file ({type(e).__name__}); write the detections with "
                          "numpy.savez (docs/tracking.md)") from None
    for key in ("frame", "camera", "uv", "rate"):
        if key not in data:
            raise CameraError(f"{path}: no array '{key}'; the file needs frame, camera, uv and rate (docs/tracking.md)")
    frame, camera, uv = data["frame"], data["camera"], data["uv"]
    n = frame.shape[0] if frame.ndim == 1 else -1
    if (n < 0 or camera.shape != (n,) or uv.shape != (n, 2) or not np.issubdtype(frame.dtype, np.integer)
            or not np.issubdtype(camera.dtype, np.integer)):
        raise CameraError(f"{path}: frame and camera must be integer arrays of one length n and uv an (n, 2) array")
    if not np.all(np.isfinite(uv)):
        raise CameraError(f"{path}: uv has non-finite pixels; leave undetected points out instead")
    rate = float(data["rate"])
    if not (rate > 0 and math.isfinite(rate)):
        raise CameraError(f"{path}: rate must be a positive number of Hz, got {rate}")
    if n and (frame.min() < 0 or camera.min() < 0):
        raise CameraError(f"{path}: negative frame or camera numbers; they are 0-based")
    nf = int(data["n_frames"]) if "n_frames" in data else (int(frame.max()) + 1 if n else 0)
    if n and frame.max() >= nf:
        raise CameraError(f"{path}: frame {int(frame.max())} beyond n_frames {nf}")
    nc = int(data["n_cameras"]) if "n_cameras" in data else (int(camera.max()) + 1 if n else 1)
    if n_cameras is not None:
        if n and camera.max() >= n_cameras:
            raise CameraError(f"{path}: camera {int(camera.max())} (0-based) but the calibration has {n_cameras} "
                              "cameras; give the calibration these detections were made with")
        nc = n_cameras
    return Detections(frame.astype(np.int64), camera.astype(np.int64), uv.astype(float), rate, nf, nc)


def write_camera_files(cameras_path: Path, cameras: Sequence[Camera], detections_path: Path,
                       detections: Detections, extra: dict[Path, dict[str, np.ndarray]] | None = None) -> None:
    """Write the calibration (TOML) and the detections (NPZ) and any `extra` NPZ files, all or none."""
    def npz(arrays):
        def write(staged: Path) -> None:
            with open(staged, "wb") as f:
                np.savez_compressed(f, **arrays)
        return write

    writers = {Path(cameras_path): lambda s: put_text(s, cameras_toml(cameras)),
               Path(detections_path): npz(detections.arrays())}
    for p, arrays in (extra or {}).items():
        writers[Path(p)] = npz(arrays)
    write_all(writers)
