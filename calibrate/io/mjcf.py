"""A calibrate model as a MuJoCo model (MJCF), and its motions as MuJoCo ``qpos``.

MuJoCo reads URDF, but not ours as a subject: its URDF import fixes the root link to the world (a subject's pelvis
would be welded in place) and refuses the massless links between one joint's rotations ("mass and inertia of moving
bodies must be larger than mjMINVAL").  The MJCF written here is what a roboticist's simulator wants instead, built
from the Pinocchio model of the URDF calibrate writes (Pinocchio is the reference for the kinematics):

* **bodies** — one per Pinocchio joint, nested as the kinematic tree, named by the URDF link it moves, at the
  joint's placement in its parent's frame (``pos``, ``quat``); the root's a ``freejoint`` named ``root``.
* **joints** — a ``hinge`` per revolute, named by the URDF joint (the motion CSV's columns), its axis in the body
  frame, its limits as ``range`` (none for a continuous joint).
* **inertia** — each body's ``inertial`` (mass, centre of mass, full inertia about it: Pinocchio's, so a segment's
  fixed links — its markers — are merged in); the massless connector bodies between one joint's rotations get a
  point-like 1 µg (1e-12 kg m²) at their origin, as MuJoCo needs a moving body to have mass (CONNECTOR_MASS).
* **markers** — ``site`` elements (7 mm spheres) on their segments, where MuJoCo's motion-capture tools expect
  them (``data.site_xpos``).
* **visuals** — each segment's URDF visuals as ``geom`` elements (sphere, box, cylinder, capsule, mesh), visual
  only (``contype``/``conaffinity`` 0, ``group`` 1, no mass), colours from the URDF materials.
* gravity along −z (models/human.urdf is z up); a model imported from OpenSim keeps its source's (y up); such a
  model's locked coordinates held at their values by ``equality`` constraints (``<joint joint1=... polycoef=.../>``).

A motion becomes ``qpos`` rows: the root's position, its quaternion in MuJoCo's order (w, x, y, z), then the hinge
angles in the bodies' order, which is Pinocchio's (calibrate.model.Model.dofs).
"""

from __future__ import annotations

import argparse
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin

from ..errors import CalibrateError
from ..model.model import Model, Parameters, urdf_text
from ..model.rotations import matrix_quats
from ..model.urdf import urdf_visuals
from .motion import Motion
from .outputs import check_targets, write_all
from .text import atomic_write_text, fmt_float, fmt_vec

# A massless connector body (between one joint's rotations) as MuJoCo takes it: a moving body needs a mass and
# inertia over mjMINVAL, so each gets this point-like one at its origin (the whole model a few µg heavier).
CONNECTOR_MASS = 1e-9  # kg
CONNECTOR_INERTIA = 1e-12  # kg m^2, each principal moment
MARKER_RADIUS = 0.007  # m, as the URDF's marker spheres


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    """MuJoCo's quaternion (w, x, y, z) of a rotation matrix; exactly (1, 0, 0, 0) for R = I."""
    if np.array_equal(R, np.eye(3)):
        return np.array([1.0, 0.0, 0.0, 0.0])
    x, y, z, w = matrix_quats(R)
    return np.array([w, x, y, z])


def _place(el: ET.Element, X: pin.SE3) -> None:
    """Set ``pos`` and ``quat`` of an MJCF element from a placement (both left out where they are the identity's)."""
    if np.any(X.translation):
        el.set("pos", fmt_vec(X.translation))
    if not np.array_equal(X.rotation, np.eye(3)):
        el.set("quat", fmt_vec(_quat_wxyz(X.rotation)))


def _geom(body: ET.Element, name: str, tag: str, X: pin.SE3, sizes: dict[str, str],
          rgba: np.ndarray | None) -> None:
    """One visual-only geom: a URDF sphere, box, cylinder, capsule or mesh at X in the body frame."""
    g = ET.SubElement(body, "geom", name=name, contype="0", conaffinity="0", group="1", mass="0")
    if tag == "sphere":
        g.set("type", "sphere")
        g.set("size", fmt_float(float(sizes["radius"])))
    elif tag == "box":
        g.set("type", "box")
        g.set("size", fmt_vec(np.array([float(v) for v in sizes["size"].split()]) / 2))
    elif tag in ("cylinder", "capsule"):  # both along z, as in URDF; MuJoCo's size: radius, half length
        g.set("type", tag)
        g.set("size", fmt_vec((float(sizes["radius"]), float(sizes["length"]) / 2)))
    else:
        g.set("type", "mesh")
        g.set("mesh", name)
    _place(g, X)
    if rgba is not None:
        g.set("rgba", fmt_vec(rgba))


def mjcf_text(model: Model, params: Parameters | None = None, mass: float | None = None) -> str:
    """The MJCF document of `model` with geometric parameters `params` (default: the model's own) and body `mass`
    (kg; default: the model's): the subject calibrate's URDF writer would write, as MuJoCo reads it."""
    from .osim_info import osim_info

    subject = model if params is None and mass is None else Model(model.path, urdf_text(model, params, mass))
    pm = subject.pin
    frames = pm.frames
    link_of = {frames[f.parentFrame].name: f.name for f in frames
               if f.type == pin.FrameType.BODY and frames[f.parentFrame].type == pin.FrameType.JOINT}
    root = ET.Element("mujoco", model=subject.path.stem)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", inertiafromgeom="false")
    info = osim_info(model)
    ET.SubElement(root, "option", gravity=fmt_vec(info.gravity if info is not None else (0.0, 0.0, -9.80665)))
    assets = ET.SubElement(root, "asset")
    world = ET.SubElement(root, "worldbody")
    bodies: dict[int, ET.Element] = {0: world}
    for j in range(1, pm.njoints):
        jm, name = pm.joints[j], pm.names[j]
        body = ET.SubElement(bodies[pm.parents[j]], "body", name=link_of.get(name, name))
        bodies[j] = body
        _place(body, pm.jointPlacements[j])
        inertia = pm.inertias[j]
        if inertia.mass > 0:
            I = inertia.inertia
            ET.SubElement(body, "inertial", pos=fmt_vec(inertia.lever), mass=fmt_float(inertia.mass),
                          fullinertia=fmt_vec((I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2])))
        else:
            ET.SubElement(body, "inertial", pos="0 0 0", mass=fmt_float(CONNECTOR_MASS),
                          diaginertia=fmt_vec([CONNECTOR_INERTIA] * 3))
        if jm.shortname() == "JointModelFreeFlyer":
            ET.SubElement(body, "freejoint", name="root")
            continue
        dof = subject.dofs[subject.dof_index(name)]  # axis in the joint frame; limits (none for a continuous joint)
        hinge = ET.SubElement(body, "joint", name=name, type="hinge", axis=fmt_vec(dof.axis))
        if np.isfinite(dof.lower) and np.isfinite(dof.upper) and dof.upper > dof.lower:
            hinge.set("range", fmt_vec((dof.lower, dof.upper)))
    visuals = urdf_visuals(subject)
    for seg in subject.segments:
        f = frames[pm.getFrameId(seg.name, pin.FrameType.BODY)]
        for k, (tag, (R, xyz), sizes, rgba) in enumerate(visuals.get(seg.name, [])):
            name = f"{seg.name}_{k}"
            if tag == "mesh":
                if not sizes["filename"]:
                    continue
                mesh = ET.SubElement(assets, "mesh", name=name, file=sizes["filename"])
                if sizes["scale"]:
                    mesh.set("scale", sizes["scale"])
            elif tag not in ("sphere", "box", "cylinder", "capsule"):
                continue
            _geom(bodies[f.parentJoint], name, tag, f.placement * pin.SE3(R, xyz), sizes, rgba)
    for marker in subject.markers:
        f = frames[pm.getFrameId(marker.name, pin.FrameType.BODY)]
        ET.SubElement(bodies[f.parentJoint], "site", name=marker.name, pos=fmt_vec(f.placement.translation),
                      size=fmt_float(MARKER_RADIUS), rgba="0.9 0.2 0.2 1")
    if not len(assets):
        root.remove(assets)
    locked = {d: v for d, v in info.locked.items() if d in set(model.dof_names)} if info else {}  # URDF angles
    if locked:  # OpenSim's locked coordinates held where the source holds them: joint1 = polycoef[0]
        equality = ET.SubElement(root, "equality")
        for d, value in locked.items():
            ET.SubElement(equality, "joint", name=f"{d}_locked", joint1=d, polycoef=fmt_vec((value, 0, 0, 0, 0)))
    ET.indent(root, "  ")
    note = (f"<!-- {subject.path.name} as a MuJoCo model, written by calibrate (calibrate.io.mjcf): one body per "
            f"joint, markers as sites; massless connector bodies at {fmt_float(CONNECTOR_MASS)} kg -->\n")
    return note + ET.tostring(root, encoding="unicode") + "\n"


def mjcf_qpos(model: Model, motion: Motion) -> np.ndarray:
    """(n_frames, 7 + n_dofs) MuJoCo ``qpos`` of `motion` for the MJCF of `model`: the root's position (m), its
    quaternion (w, x, y, z), then the joint angles (rad) in the model's order (Pinocchio's, the MJCF bodies')."""
    missing = [d for d in model.dof_names if d not in motion.dof_names]
    if missing:
        raise CalibrateError(f"the motion has no angle of {model.path.name}'s joint '{missing[0]}' ({len(missing)} "
                             f"missing); is it a motion of this model?")
    index = [motion.dof_names.index(d) for d in model.dof_names]
    q = motion.root_quaternion
    return np.hstack([motion.root_translation, q[:, [3, 0, 1, 2]], motion.angles[:, index]])


def qpos_columns(model: Model) -> list[str]:
    """The header of a qpos CSV: time, the root's position and quaternion (w, x, y, z), the joints by name."""
    return ["time", "root_x", "root_y", "root_z", "root_qw", "root_qx", "root_qy", "root_qz", *model.dof_names]


def qpos_csv_text(model: Model, motion: Motion) -> str:
    """A motion as a CSV of MuJoCo qpos rows (one per frame), headed by qpos_columns."""
    rows = np.column_stack([motion.times, mjcf_qpos(model, motion)])
    return ",".join(qpos_columns(model)) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n"


def export_mjcf(model: Model, path: str | os.PathLike[str], params: Parameters | None = None,
                overwrite: bool = True) -> Path:
    """Write `model` (with `params`, default its own) as a MuJoCo MJCF file at `path`; nothing half-written."""
    path = Path(path)
    check_targets([path], overwrite, inputs={model.path: "that is the model; refusing to overwrite it"})
    text = mjcf_text(model, params)
    try:
        atomic_write_text(path, text)
    except OSError as e:
        raise CalibrateError(f"{path}: cannot write ({e.strerror}); choose a writable place") from None
    return path


# ---------------------------------------------------------------------- the command line
def add_export_mjcf_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``export-mjcf`` to the CLI's subparsers."""
    p = subparsers.add_parser(
        "export-mjcf", prog="calibrate export-mjcf",
        help="write a model as a MuJoCo model (MJCF .xml), a motion as MuJoCo qpos rows",
        description="Write MODEL (a calibrate URDF, e.g. a calibrated subject.urdf, or an .osim) as a MuJoCo model: "
                    "a free root, one hinge per revolute, the inertias, the markers as sites, the URDF's visuals.  "
                    "Optionally also a motion CSV of the model as MuJoCo qpos rows (CSV: time, root position, "
                    "quaternion w x y z, joint angles).  Existing files are kept unless --overwrite.")
    p.add_argument("model", type=Path, metavar="MODEL",
                   help="the model (.urdf or .osim), e.g. a calibrated subject.urdf")
    p.add_argument("--marker-set", type=Path, default=None, metavar="XML",
                   help="for an .osim MODEL: an OpenSim MarkerSet file whose markers are added, replacing those of "
                        "the same name")
    p.add_argument("-o", "--output", type=Path, default=None, metavar="XML",
                   help="the MJCF file to write (default: MODEL's name + _mujoco.xml)")
    p.add_argument("--motion", type=Path, default=None, metavar="CSV", help="a motion CSV of MODEL to write as qpos")
    p.add_argument("--qpos", type=Path, default=None, metavar="CSV",
                   help="the qpos CSV to write (default: CSV's name + _qpos.csv)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    return p


def cmd_export_mjcf(args: argparse.Namespace) -> int:
    """``calibrate export-mjcf``: check every destination, build every file, then write them all."""
    from ..model.model import load_model
    from .motion import read_motion_csv

    model_path: Path = args.model
    if args.qpos is not None and args.motion is None:
        raise CalibrateError(f"{args.qpos}: --qpos needs --motion (the motion CSV to convert)")
    targets = {"xml": args.output or model_path.with_name(model_path.stem + "_mujoco.xml")}
    if args.motion is not None:
        targets["qpos"] = args.qpos or args.motion.with_name(args.motion.stem + "_qpos.csv")
    for kind, path in targets.items():
        suffix = ".xml" if kind == "xml" else ".csv"
        if path.suffix.lower() != suffix:
            raise CalibrateError(f"{path}: the {'MJCF model' if kind == 'xml' else 'qpos'} output should end in "
                                 f"{suffix}; rename it")
    sources = [s for s in (model_path, args.motion, args.marker_set) if s is not None]
    check_targets(list(targets.values()), args.overwrite,
                  inputs={s: "that is an input file; refusing to overwrite it (choose another name)" for s in sources},
                  same="the MJCF and qpos outputs must be different files")
    model = load_model(model_path, args.marker_set)
    texts = {"xml": mjcf_text(model)}
    motion = None
    if args.motion is not None:
        motion = read_motion_csv(args.motion)
        try:
            texts["qpos"] = qpos_csv_text(model, motion)
        except CalibrateError as e:
            raise CalibrateError(f"{args.motion}: {e}") from None
    writers = {path: (lambda p, kind=kind: atomic_write_text(p, texts[kind])) for kind, path in targets.items()}
    try:
        write_all(writers)
    except OSError as e:
        raise CalibrateError(f"{targets['xml'].parent}: cannot write ({e.strerror}); choose a writable place") \
            from None
    print(model.summary())
    print(f"wrote {targets['xml']}  (MuJoCo: a free root, {model.n_dofs} hinges, {len(model.markers)} marker sites)")
    if motion is not None:
        print(f"      {targets['qpos']}  ({motion.n_frames} frames of qpos: root position, quaternion w x y z, "
              f"angles in radians)")
    return 0


__all__ = ["add_export_mjcf_parser", "cmd_export_mjcf", "export_mjcf", "mjcf_qpos", "mjcf_text", "qpos_columns",
           "qpos_csv_text"]
