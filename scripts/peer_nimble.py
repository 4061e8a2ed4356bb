"""Peer: nimblephysics' MarkerFitter (the engine of AddBiomechanics) on an exported .osim.

nimblephysics segfaults under numpy >= 2, so it runs in a venv of its own (numpy < 2, made once
by :func:`ensure_venv`) through ``scripts/_nimble_worker.py``, with JSON files in and out.  This
module imports neither nimblephysics nor anything outside the standard library, numpy and scipy
at module level.

nimble reads only part of OpenSim: a ``CustomJoint`` with three rotations must have them about
x, y, z in one of the orders XYZ, XZY, ZXY, ZYX (signs allowed), and its y axis is "up" for the
height prior.  :func:`nimble_osim_text` rewrites an .osim into an equivalent one nimble reads:
the same bodies, markers and coordinates with the same meaning, with

* a two- or three-rotation ``CustomJoint`` with orthogonal axes → axes x, y (, ±z), both joint
  frames turned by the same rotation (nimble reads one-rotation CustomJoints about any axis),
* the ground frame turned so that up (against gravity) is y; the trial is turned the same way
  in the worker and every result turned back, so all results are in the lab frame of the .trc.

Usage (a self-test on a synthetic squat of models/human.urdf)::

    python scripts/peer_nimble.py --selftest [--frames 1000]
    python scripts/peer_nimble.py --osim M.osim --trc T.trc --mass 75 --height 1.75 [--out R.json]
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

NIMBLE_VERSION = "0.10.52.1"  # the newest on PyPI when written; cp311 wheel
DEFAULT_VENV = Path.home() / ".cache" / "calibrate" / "nimble-venv"
WORKER = Path(__file__).resolve().with_name("_nimble_worker.py")
_STAMP = ".calibrate-nimble"  # written into the venv once it works; holds the package spec
_SPEC = f"nimblephysics=={NIMBLE_VERSION} numpy<2 (--no-deps: nimble's torch dependency is not needed)"


# ---------------------------------------------------------------------------------------------- venv
def _venv_python(path: Path) -> Path:
    return path / "bin" / "python"


def _run(cmd: list[str], what: str, timeout: float = 1800) -> None:
    """Run a setup step; RuntimeError with its last output line if it fails."""
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RuntimeError(f"nimble venv: {what} failed: {' '.join(str(exc).split())}") from None
    if proc.returncode != 0:
        lines = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip() and "WARNING" not in ln]
        raise RuntimeError(f"nimble venv: {what} failed: {lines[-1].strip() if lines else proc.returncode}")


def ensure_venv(path: Path | None = None) -> Path:
    """The python of a venv with nimblephysics and numpy < 2 at `path` (default
    ~/.cache/calibrate/nimble-venv), created on first use; RuntimeError (one line) if that fails.

    nimblephysics is installed without its declared dependencies: it pulls in torch (with CUDA
    wheels, gigabytes), which only its Python helpers use; the worker imports the native module.
    """
    venv = Path(path) if path is not None else DEFAULT_VENV
    python = _venv_python(venv)
    stamp = venv / _STAMP
    if python.exists() and stamp.exists() and stamp.read_text().strip() == _SPEC:
        return python
    try:
        venv.parent.mkdir(parents=True, exist_ok=True)
        return _create_venv(venv)
    except OSError as exc:
        raise RuntimeError(f"nimble venv: cannot create {venv}: {' '.join(str(exc).split())}") from None


def _create_venv(venv: Path) -> Path:
    """Create the venv of :func:`ensure_venv` under a lock (another process may be making it)."""
    python = _venv_python(venv)
    stamp = venv / _STAMP
    with open(venv.parent / f".{venv.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one creator at a time; the others then find it made
        if python.exists() and stamp.exists() and stamp.read_text().strip() == _SPEC:
            return python
        if venv.exists():
            shutil.rmtree(venv)
        try:
            _run([sys.executable, "-m", "venv", str(venv)], "creating the venv")
            pip = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
            _run(pip + ["numpy<2"], "pip install numpy<2")
            nimble = f"nimblephysics=={NIMBLE_VERSION}"
            _run(pip + ["--no-deps", nimble], f"pip install {nimble}")
            _run([str(python), "-I", "-c", "import numpy, sys; from nimblephysics_libs import _nimblephysics; "
                  "sys.exit(int(numpy.__version__.split('.')[0]) >= 2)"], "importing nimblephysics")
        except BaseException:
            shutil.rmtree(venv, ignore_errors=True)
            raise
        stamp.write_text(_SPEC + "\n")
    return python


# ------------------------------------------------------------------------------------- .osim rewrite
def _floats(text: str | None) -> np.ndarray:
    return np.array([float(v) for v in (text or "").split()], dtype=float)


def _fmt(v: np.ndarray) -> str:
    return " ".join(repr(float(x)) for x in v)


def _euler_xyz_matrix(angles: np.ndarray) -> np.ndarray:
    """OpenSim's frame orientation: body-fixed X-Y-Z Euler angles."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("XYZ", angles).as_matrix()


def _matrix_euler_xyz(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_euler("XYZ")


def _turn_frames(joint: ET.Element, C: np.ndarray) -> None:
    """Right-multiply the orientation of both joint frames by C (the joint's motion then
    happens about C.T-turned axes)."""
    names = {joint.findtext("socket_parent_frame", "").strip(), joint.findtext("socket_child_frame", "").strip()}
    for frame in joint.iter("PhysicalOffsetFrame"):
        if frame.get("name") in names:
            node = frame.find("orientation")
            if node is None:
                node = ET.SubElement(frame, "orientation")
            node.text = _fmt(_matrix_euler_xyz(_euler_xyz_matrix(_floats(node.text) if node.text else np.zeros(3)) @ C))


def _transform_axes(joint: ET.Element) -> list[tuple[ET.Element, str, np.ndarray, bool]] | None:
    """(element, coordinate, unit axis, is identity function) of the six TransformAxis, or None if
    any is other than identity-of-one-coordinate or constant 0."""
    out = []
    for ta in joint.iter("TransformAxis"):
        coord = (ta.findtext("coordinates") or "").strip()
        axis = _floats(ta.findtext("axis"))
        lin, const = ta.find("LinearFunction"), ta.find("Constant")
        if coord and lin is not None and np.allclose(_floats(lin.findtext("coefficients")), [1, 0]):
            out.append((ta, coord, axis / np.linalg.norm(axis), True))
        elif not coord and const is not None and float(const.findtext("value") or 0) == 0:
            out.append((ta, "", axis / np.linalg.norm(axis), False))
        else:
            return None
    return out if len(out) == 6 else None


def _rewrite_joint(joint: ET.Element, notes: list[str]) -> None:
    """Rewrite one CustomJoint in place so nimble reads it."""
    name = joint.get("name")
    axes = _transform_axes(joint)
    if axes is None:
        notes.append(f"{name}: left as is (functions other than identity / constant 0)")
        return
    rot = [(ta, c, a) for ta, c, a, on in axes[:3] if on]
    if any(on for _, _, _, on in axes[3:]) or not rot:
        return  # translating (the root) or fixed: nimble reads the root's ZYX + translations as is
    b = [a for _, _, a in rot]
    if len(rot) == 1:
        return  # nimble reads a one-rotation CustomJoint, about any axis, as a RevoluteJoint
    if not all(on for _, _, _, on in axes[:len(rot)]):
        notes.append(f"{name}: coordinates not in the first rotation slots, left as is (nimble may reject it)")
        return
    gram = np.array([[x @ y for y in b] for x in b])
    if not np.allclose(gram, np.eye(len(b)), atol=1e-9):
        notes.append(f"{name}: rotation axes not orthogonal, left as is (nimble may reject it)")
        return
    third = np.cross(b[0], b[1])
    C = np.column_stack([b[0], b[1], third])
    new = [np.eye(3)[0], np.eye(3)[1], np.eye(3)[2]]
    if len(rot) == 3:
        new[2] = C.T @ b[2]  # ±z
    _turn_frames(joint, C)
    for (ta, _, _), a in zip(rot, new, strict=False):
        ta.find("axis").text = _fmt(np.round(a, 12))
    if len(rot) == 2:  # the constant third rotation about z: completes the axis set nimble expects
        axes[2][0].find("axis").text = "0 0 1"
    if not all(np.allclose(np.abs(x), np.round(np.abs(x))) for x in b):
        notes.append(f"{name}: axes {[np.round(x, 4).tolist() for x in b]} -> x, y{', ±z' if len(rot) == 3 else ''}")
    elif [int(np.argmax(np.abs(x))) for x in b] not in ([0, 1, 2], [0, 2, 1], [2, 1, 0], [2, 0, 1], [0, 1]):
        notes.append(f"{name}: axis order {''.join('XYZ'[int(np.argmax(np.abs(x)))] for x in b)} -> XY"
                     f"{'Z' if len(rot) == 3 else ''} (frames turned)")


def _up_rotation(gravity: np.ndarray) -> np.ndarray:
    """The rotation taking -gravity to +y (identity if gravity is already along -y)."""
    up = -gravity / np.linalg.norm(gravity)
    y = np.array([0.0, 1.0, 0.0])
    v, c = np.cross(up, y), float(up @ y)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1 + c)


def nimble_osim_text(text: str) -> tuple[str, np.ndarray, list[str]]:
    """An .osim's text rewritten so nimble reads it with the same kinematics (module docstring);
    returns (text, lab_to_nimble rotation, notes on what changed)."""
    root = ET.fromstring(text)
    model = root.find("Model")
    if model is None:
        raise ValueError("no <Model> in the .osim")
    notes: list[str] = []
    objects = model.find("JointSet/objects")
    for joint in list(objects if objects is not None else []):
        if joint.tag == "CustomJoint":
            _rewrite_joint(joint, notes)
    g = _floats(model.findtext("gravity")) if model.find("gravity") is not None else np.array([0.0, -9.80665, 0.0])
    R0 = _up_rotation(g)
    if not np.allclose(R0, np.eye(3)):
        model.find("gravity").text = _fmt(R0 @ g)
        for joint in list(objects if objects is not None else []):
            parent = joint.findtext("socket_parent_frame", "").strip()
            for frame in joint.iter("PhysicalOffsetFrame"):
                if frame.get("name") == parent and frame.findtext("socket_parent", "").strip() in ("/ground", "ground"):
                    R = _euler_xyz_matrix(_floats(frame.findtext("orientation")))
                    t = _floats(frame.findtext("translation"))
                    frame.find("orientation").text = _fmt(_matrix_euler_xyz(R0 @ R))
                    frame.find("translation").text = _fmt(R0 @ t)
        notes.append(f"ground turned so that up {np.round(-g / np.linalg.norm(g), 4).tolist()} is nimble's y")
    return ET.tostring(root, encoding="unicode"), R0, notes


# ------------------------------------------------------------------------------------------- meshes
Mesh = tuple[np.ndarray, np.ndarray]  # vertices (n, 3), triangles (m, 3)


def _box(half: np.ndarray) -> Mesh:
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float) * half
    f = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4),
         (1, 5, 7), (1, 7, 3)]
    return v, np.array(f)


def _cylinder(radius: float, length: float, n: int = 16) -> Mesh:
    a = 2 * np.pi * np.arange(n) / n
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    v = np.vstack([np.column_stack([ring, np.full(n, -length / 2)]), np.column_stack([ring, np.full(n, length / 2)]),
                   [[0, 0, -length / 2], [0, 0, length / 2]]])
    f = []
    for i in range(n):
        j = (i + 1) % n
        f += [(i, j, n + j), (i, n + j, n + i), (2 * n, j, i), (2 * n + 1, n + i, n + j)]
    return v, np.array(f)


def _sphere(radius: float, n_lat: int = 8, n_lon: int = 16) -> Mesh:
    lat = np.pi * np.arange(1, n_lat) / n_lat
    lon = 2 * np.pi * np.arange(n_lon) / n_lon
    v = [[0, 0, radius], [0, 0, -radius]]
    v += [[radius * np.sin(t) * np.cos(p), radius * np.sin(t) * np.sin(p), radius * np.cos(t)]
          for t in lat for p in lon]
    f = []
    for k in range(n_lon):
        kk = (k + 1) % n_lon
        f += [(0, 2 + k, 2 + kk), (1, 2 + (n_lat - 2) * n_lon + kk, 2 + (n_lat - 2) * n_lon + k)]
        for r in range(n_lat - 2):
            a, b = 2 + r * n_lon, 2 + (r + 1) * n_lon
            f += [(a + k, b + k, b + kk), (a + k, b + kk, a + kk)]
    return np.array(v, dtype=float), np.array(f)


def _merge(meshes: list[Mesh]) -> Mesh:
    verts, faces, n = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.vstack(verts), np.vstack(faces)


def urdf_visual_meshes(urdf: Path) -> dict[str, Mesh]:
    """Each link's box / cylinder / sphere visuals as one triangle mesh in the link frame."""
    from scipy.spatial.transform import Rotation

    out: dict[str, list[Mesh]] = {}
    for link in ET.parse(urdf).getroot().iter("link"):
        for vis in link.iter("visual"):
            origin = vis.find("origin")
            xyz = _floats(origin.get("xyz")) if origin is not None and origin.get("xyz") else np.zeros(3)
            rpy = _floats(origin.get("rpy")) if origin is not None and origin.get("rpy") else np.zeros(3)
            geo = vis.find("geometry")
            shape = None
            if geo is not None and geo.find("box") is not None:
                shape = _box(_floats(geo.find("box").get("size")) / 2)
            elif geo is not None and geo.find("cylinder") is not None:
                c = geo.find("cylinder")
                shape = _cylinder(float(c.get("radius")), float(c.get("length")))
            elif geo is not None and geo.find("sphere") is not None:
                shape = _sphere(float(geo.find("sphere").get("radius")))
            if shape is not None:
                R = Rotation.from_euler("xyz", rpy).as_matrix()
                out.setdefault(link.get("name"), []).append((shape[0] @ R.T + xyz, shape[1]))
    return {k: _merge(v) for k, v in out.items()}


def osim_point_meshes(root: ET.Element, pad: float = 0.02) -> dict[str, Mesh]:
    """Each body's box around its markers and joint-frame origins (padded): a stand-in shape."""
    points: dict[str, list[np.ndarray]] = {}
    for frame in root.iter("PhysicalOffsetFrame"):
        body = frame.findtext("socket_parent", "").strip().split("/")[-1]
        points.setdefault(body, []).append(_floats(frame.findtext("translation")) if frame.find("translation")
                                           is not None else np.zeros(3))
    for marker in root.iter("Marker"):
        body = marker.findtext("socket_parent_frame", "").strip().split("/")[-1]
        points.setdefault(body, []).append(_floats(marker.findtext("location")))
    out = {}
    for body, pts in points.items():
        if body == "ground":
            continue
        P = np.vstack([np.zeros(3), *pts])
        lo, hi = P.min(axis=0) - pad, P.max(axis=0) + pad
        v, f = _box((hi - lo) / 2)
        out[body] = (v + (hi + lo) / 2, f)
    return out


def _write_ply(path: Path, mesh: Mesh) -> None:
    v, f = mesh
    head = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x", "property float y",
            "property float z", f"element face {len(f)}", "property list uchar int vertex_indices", "end_header"]
    path.write_text("\n".join(head + [f"{a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
                              + [f"3 {a} {b} {c}" for a, b, c in f]) + "\n")


def attach_meshes(text: str, meshes: dict[str, Mesh], folder: Path) -> str:
    """`text` (an .osim) with each body in `meshes` given its mesh, written as PLY into `folder`
    (nimble loads ``<mesh_file>NAME</mesh_file>`` as ``folder/NAME.ply``)."""
    root = ET.fromstring(text)
    folder.mkdir(parents=True, exist_ok=True)
    for body in root.iter("Body"):
        name = body.get("name") or ""
        if name not in meshes:
            continue
        _write_ply(folder / f"shape_{name}.ply", meshes[name])
        old = body.find("attached_geometry")
        if old is not None:
            body.remove(old)
        geo = ET.Element("attached_geometry")
        mesh = ET.SubElement(geo, "Mesh", name=f"shape_{name}")
        ET.SubElement(mesh, "socket_frame").text = ".."
        ET.SubElement(mesh, "scale_factors").text = "1 1 1"
        ET.SubElement(mesh, "mesh_file").text = f"shape_{name}"
        body.insert(0, geo)
    return ET.tostring(root, encoding="unicode")


# ------------------------------------------------------------------------------------------ running
def _call_worker(python: Path, request: dict[str, Any], work: Path, timeout_s: float) -> dict[str, Any]:
    """Run the worker on `request`; its answer, or {"error": ...} (crash, timeout, no answer)."""
    req, ans, log = work / "request.json", work / "answer.json", work / "worker.log"
    req.write_text(json.dumps(request))
    ans.unlink(missing_ok=True)
    with open(log, "w") as fh:
        proc = subprocess.Popen([str(python), "-I", str(WORKER), str(req), str(ans)], stdout=fh,
                                stderr=subprocess.STDOUT, start_new_session=True)
        try:
            code = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            return {"error": f"nimble worker timed out after {timeout_s:.0f} s (log: {log})"}
    if ans.exists():
        return json.loads(ans.read_text())
    tail = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()][-1:]
    why = f"signal {-code}" if code < 0 else f"exit {code}"
    return {"error": f"nimble worker died ({why}){': ' + tail[0] if tail else ''} (log: {log})"}


def prepare_osim(osim_path: Path, work: Path, urdf: Path | None = None) -> tuple[Path, np.ndarray, list[str]]:
    """Write the nimble-readable copy of `osim_path` into `work`, with a mesh on every body
    (nimble's pipeline measures the model's height on its meshes and fails without): the
    URDF's visuals if `urdf` is given, else boxes around each body's markers and joints."""
    text, R0, notes = nimble_osim_text(Path(osim_path).read_text())
    if urdf is not None:
        meshes = urdf_visual_meshes(Path(urdf))
        notes.append(f"meshes: the visuals of {Path(urdf).name}")
    else:
        meshes = osim_point_meshes(ET.fromstring(text))
        notes.append("meshes: boxes around each body's markers and joint frames (no URDF given)")
    text = attach_meshes(text, meshes, work / "Geometry")
    out = work / "model_nimble.osim"
    out.write_text(text)
    return out, R0, notes


def scaled_osim(osim_path: Path, body_scales: dict[str, list[float]], markers: dict[str, list], out: Path) -> Path:
    """`osim_path` with nimble's fitted body scales applied to the joint frames' translations and
    nimble's fitted marker offsets (its own scaling of the model; nimble writes no .osim without
    OpenSim's ScaleTool)."""
    root = ET.fromstring(Path(osim_path).read_text())
    model = root.find("Model")
    for frame in model.iter("PhysicalOffsetFrame"):
        body = frame.findtext("socket_parent", "").strip().split("/")[-1]
        if body in body_scales and frame.find("translation") is not None:
            scaled = _floats(frame.findtext("translation")) * np.asarray(body_scales[body])
            frame.find("translation").text = _fmt(scaled)
    for marker in model.iter("Marker"):
        fit = markers.get(marker.get("name") or "")
        if fit is not None and marker.find("location") is not None:
            body, offset = fit
            marker.find("location").text = _fmt(np.asarray(offset) * np.asarray(body_scales.get(body, [1, 1, 1])))
    out.write_text(ET.tostring(root, encoding="unicode"))
    return out


def _failure(reason: str, **extra: Any) -> dict[str, Any]:
    return {"time_s": None, "marker_rms_m": None, "centres_world": {}, "axes_world": {}, "angles": {},
            "scaled_osim": None, "error": " ".join(reason.split()), **extra}


def run_nimble(osim_path: Path, trc_paths: list[Path], *, mass_kg: float, height_m: float, timeout_s: float = 1800,
               venv: Path | None = None, work_dir: Path | None = None, urdf: Path | None = None,
               settings: dict[str, Any] | None = None) -> dict[str, Any]:
    """Fit `osim_path` to the trials with nimble's MarkerFitter (AddBiomechanics' kinematics pass).

    Returns time_s (the fit: marker clean-up and runMultiTrialKinematicsPipeline), total_s (all,
    venv included), venv_s, import_s, load_s, extract_s; marker_rms_m (RMS over all observed
    markers and frames of the first trial), centres_world {joint: (n, 3)}, axes_world {hinge:
    (n, 3)}, angles {coordinate: (n,)} (lab frame of the .trc, the first trial's frames in order;
    ``trials`` holds every trial), body_scales, markers (fitted offsets), scaled_osim, notes,
    work_dir (request, answer, worker.log), error (None or one line).  Never raises for a
    failed fit: the reason is in ``error``.

    `urdf` (the model the .osim was exported from) gives the bodies its visuals as meshes: nimble
    needs meshes, and with them the height prior (AddBiomechanics': `height_m`, weight 0.1, on
    the model's meshes at the zero pose) is meaningful; without, the bodies get boxes around their
    markers and the height prior is off unless settings ask for it.

    `settings` (all optional): iterations (500), initial_ik_restarts (150), bilevel_samples (150),
    symmetric (True: left/right share scales, as AddBiomechanics), height_prior (True with a
    URDF), clean_markers (True), ignore_joint_limits (False), analytical_ik (nimble's default),
    marker_positions (False; True: every trial's model markers per frame, lab frame, as ``markers_world``
    (n, m, 3) in the order of ``marker_names`` in ``trials``), markers ("addbiomechanics":
    AddBiomechanics' rule, which with <= 10 markers marked
    ``<fixed>true</fixed>`` treats every marker not named like a triad (…1/2/3) as anatomical, its
    offset held near the model's (weight 10); "file": the .osim's ``<fixed>false</fixed>`` markers
    tracking (weight 0.05), free to move).
    """
    t0 = time.perf_counter()
    work = Path(work_dir) if work_dir is not None else Path(tempfile.mkdtemp(prefix="calibrate-nimble-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        python = ensure_venv(venv)
    except RuntimeError as exc:
        return _failure(str(exc), work_dir=str(work))
    venv_s = time.perf_counter() - t0
    try:
        model, R0, notes = prepare_osim(Path(osim_path), work, urdf)
    except (OSError, ValueError, ET.ParseError) as exc:
        return _failure(f"cannot read {osim_path}: {exc}", work_dir=str(work))
    cfg = {"height_prior": urdf is not None, **(settings or {})}
    request = {"mode": "fit", "osim": str(model), "geometry": f"{work / 'Geometry'}/",
               "trcs": [str(Path(p).resolve()) for p in trc_paths], "mass_kg": float(mass_kg),
               "height_m": float(height_m), "lab_to_nimble": R0.tolist(), "settings": cfg}
    ans = _call_worker(python, request, work, timeout_s)
    total_s = time.perf_counter() - t0
    if ans.get("error"):
        return _failure(ans["error"], total_s=total_s, venv_s=venv_s, notes=notes, work_dir=str(work))
    trials = [{**tr, "centres_world": {k: np.asarray(v) for k, v in tr.get("centres_world", {}).items()},
               "axes_world": {k: np.asarray(v) for k, v in tr.get("axes_world", {}).items()},
               "angles": {k: np.asarray(v) for k, v in tr.get("angles", {}).items()}} for tr in ans["trials"]]
    first = trials[0]
    scaled = None
    try:
        target = work / "model_scaled_nimble.osim"
        scaled = str(scaled_osim(Path(osim_path), ans["body_scales"], ans["markers"], target))
    except (OSError, ValueError, KeyError, ET.ParseError) as exc:
        notes.append(f"scaled .osim not written: {exc}")
    return {
        "time_s": ans["fit_s"], "total_s": total_s, "venv_s": venv_s, "import_s": ans["import_s"],
        "load_s": ans["load_s"], "extract_s": ans["extract_s"],
        "marker_rms_m": first.get("marker_rms_m"), "nimble_ik_rms_m": first.get("nimble_ik_rms_m"),
        "centres_world": first.get("centres_world", {}), "axes_world": first.get("axes_world", {}),
        "angles": first.get("angles", {}), "trials": trials, "body_scales": ans["body_scales"],
        "markers": ans["markers"], "scaled_osim": scaled, "notes": notes + ans.get("notes", []),
        "work_dir": str(work), "error": first.get("error"),
    }


def nimble_fk(osim_path: Path, coordinates: dict[str, np.ndarray], venv: Path | None = None,
              timeout_s: float = 600, urdf: Path | None = None) -> dict[str, Any]:
    """nimble's marker positions (n, m, 3) and joint centres of the unfitted .osim (after the
    rewrite) at the given coordinate values (n,) each; lab frame."""
    python = ensure_venv(venv)
    with tempfile.TemporaryDirectory(prefix="calibrate-nimble-fk-") as d:
        work = Path(d)
        model, R0, notes = prepare_osim(Path(osim_path), work, urdf)
        request = {"mode": "fk", "osim": str(model), "geometry": f"{work / 'Geometry'}/", "lab_to_nimble": R0.tolist(),
                   "coordinates": {k: np.atleast_1d(np.asarray(v, dtype=float)).tolist()
                                   for k, v in coordinates.items()}}
        ans = _call_worker(python, request, work, timeout_s)
    if ans.get("error"):
        raise RuntimeError(ans["error"])
    ans["markers_world"] = np.asarray(ans["markers_world"])
    ans["notes"] = notes
    return ans


def check_against_model(model: Any, osim_path: Path, n_poses: int = 20, seed: int = 0,
                        params: Any = None) -> dict[str, Any]:
    """Compare nimble's reading of `osim_path` (exported from `model`) with calibrate's own
    kinematics (Pinocchio) at random poses: max marker and joint-centre distances (m)."""
    from scipy.spatial.transform import Rotation

    from calibrate.io.motion import Motion
    from calibrate.io.osim_export import mot_columns
    from calibrate.model.kinematics import build_kinematics

    rng = np.random.default_rng(seed)
    p = params if params is not None else model.parameters()
    lo = np.array([d.lower if np.isfinite(d.lower) else -np.pi for d in model.dofs])
    hi = np.array([d.upper if np.isfinite(d.upper) else np.pi for d in model.dofs])
    angles = lo + (hi - lo) * rng.uniform(0.1, 0.9, (n_poses, len(model.dofs)))
    quat = Rotation.random(n_poses, random_state=seed).as_quat()  # x, y, z, w
    root = rng.uniform(-1, 1, (n_poses, 3))
    kin = build_kinematics(model)
    markers, centres = kin.batch(np.hstack([np.zeros((n_poses, 6)), angles]), quat, p)
    markers = markers + root[:, None, :]
    centres = centres + root[:, None, :]
    motion = Motion(np.arange(n_poses, dtype=float), root, quat, angles, model.dof_names)
    cols, values = mot_columns(model, motion)
    coords = {c: values[:, i] for i, c in enumerate(cols) if c != "time"}  # rad and m
    ans = nimble_fk(osim_path, coords)
    names = ans["marker_names"]
    index = {n: i for i, n in enumerate(model.marker_names)}
    ours = markers[:, [index[n] for n in names], :]
    marker_err = np.linalg.norm(ans["markers_world"] - ours, axis=2)
    joint_err = {}
    for j, jn in enumerate(j.name for j in model.joints):
        if jn in ans["centres_world"]:
            joint_err[jn] = float(np.max(np.linalg.norm(np.asarray(ans["centres_world"][jn]) - centres[:, j], axis=1)))
    worst = max(range(len(names)), key=lambda k: marker_err[:, k].max())
    return {"max_marker_m": float(marker_err.max()), "worst_marker": names[worst],
            "max_centre_m": max(joint_err.values()) if joint_err else float("nan"), "centre_m": joint_err,
            "joints": ans["joints"], "notes": ans["notes"]}


# ---------------------------------------------------------------------------------------------- CLI
def _selftest(frames: int, out: Path | None) -> int:
    """Export models/human.urdf, simulate a squat, check nimble's reading, fit, print a summary."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from calibrate import load_model
    from calibrate.io.osim_export import export_osim
    from calibrate.io.trc import write_trc
    from calibrate.simulation.simulate import simulate_squats

    work = Path(tempfile.mkdtemp(prefix="calibrate-nimble-selftest-"))
    t = time.perf_counter()
    ensure_venv()
    print(f"venv ready in {time.perf_counter() - t:.1f} s")
    urdf = Path(__file__).resolve().parents[1] / "models" / "human.urdf"
    model = load_model(urdf)
    osim = work / "human.osim"
    export_osim(model, osim)
    chk = check_against_model(model, osim)
    print(f"nimble vs calibrate kinematics: max marker {chk['max_marker_m'] * 1000:.3f} mm "
          f"({chk['worst_marker']}), max joint centre {chk['max_centre_m'] * 1000:.3f} mm")
    for note in chk["notes"]:
        print(f"  rewrite: {note}")
    sim = simulate_squats(model, frames=frames)
    trc = work / "squat.trc"
    write_trc(trc, sim.trial)
    res = run_nimble(osim, [trc], mass_kg=75.0, height_m=1.75, work_dir=work, urdf=urdf)
    if res["error"]:
        print(f"nimble failed: {res['error']}")
        return 1
    print(f"fit {res['time_s']:.1f} s (total {res['total_s']:.1f} s, import {res['import_s']:.2f} s, "
          f"load {res['load_s']:.2f} s, extract {res['extract_s']:.1f} s); "
          f"marker RMS {res['marker_rms_m'] * 1000:.2f} mm "
          f"(nimble's IK report {res['nimble_ik_rms_m'] * 1000:.2f} mm)")
    names = [j.name for j in model.joints]
    errs = {jn: float(np.sqrt(np.mean(np.sum((res["centres_world"][jn] - sim.clean_centres[:, j]) ** 2, axis=1))))
            for j, jn in enumerate(names) if jn in res["centres_world"]}
    print("joint-centre RMS vs truth (mm): " + ", ".join(f"{k} {v * 1000:.1f}" for k, v in errs.items()))
    if out is not None:
        out.write_text(json.dumps({"centre_rms_m": errs, **{k: v for k, v in res.items() if k in (
            "time_s", "total_s", "marker_rms_m", "nimble_ik_rms_m", "body_scales", "notes", "work_dir")}}, indent=1))
    print(f"files in {work}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Command line: a fit of given files, or the self-test."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--selftest", action="store_true", help="export, simulate, check and fit models/human.urdf")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--osim", type=Path)
    ap.add_argument("--trc", type=Path, action="append", default=[])
    ap.add_argument("--mass", type=float, default=75.0)
    ap.add_argument("--height", type=float, default=-1.0)
    ap.add_argument("--out", type=Path, help="write the summary / result as JSON here")
    args = ap.parse_args(argv)
    if args.selftest:
        return _selftest(args.frames, args.out)
    if args.osim is None or not args.trc:
        ap.error("give --osim and --trc (or --selftest)")
    res = run_nimble(args.osim, args.trc, mass_kg=args.mass, height_m=args.height)
    if args.out is not None:
        args.out.write_text(json.dumps(res, default=lambda a: a.tolist() if isinstance(a, np.ndarray) else str(a)))
    print(f"error: {res['error']}" if res["error"] else
          f"fit {res['time_s']:.1f} s, marker RMS {res['marker_rms_m'] * 1000:.2f} mm; files in {res['work_dir']}")
    return 0 if res["error"] is None else 1


if __name__ == "__main__":
    sys.exit(main())
