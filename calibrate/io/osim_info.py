"""What an imported OpenSim model carries beyond the URDF (calibrate.io.osim): its locked coordinates,
approximations and root coordinates, read back from the URDF's <osim> element."""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Collection
from pathlib import Path

import numpy as np

from calibrate.io.osim import FLOATING, LEFT_OUT, NO_MARKER_EFFECT, Approximation, Mix, OsimInfo, RootInfo, Together
from calibrate.io.osim_read import xml_floats

from ..errors import ModelError
from ..model.rotations import euler_matrices, matrix_eulers, quat_matrices
from ..seed.geometry import Transform


def osim_info(model) -> OsimInfo | None:
    """The OpenSim facts of a model imported from a .osim (or written from one), else None."""
    try:
        robot = ET.fromstring(model.text)
    except ET.ParseError:  # pragma: no cover - a Model's text is valid XML
        return None
    el = robot.find("opensim")
    if el is None:
        return None

    def X(e: ET.Element | None) -> Transform:
        xyz = xml_floats(e.get("xyz", "0 0 0")) if e is not None else np.zeros(3)
        rpy = xml_floats(e.get("rpy", "0 0 0")) if e is not None else np.zeros(3)
        R = np.eye(3) if not np.any(rpy) else euler_matrices("xyz", rpy)
        return R, xyz

    root = None
    r = el.find("root")
    if r is not None:
        root = RootInfo(r.get("joint", ""), X(r.find("parent_offset")), X(r.find("child_offset")),
                        tuple((e.get("coordinate", ""), xml_floats(e.get("axis"))) for e in r.findall("rotation")),
                        tuple((e.get("coordinate", ""), xml_floats(e.get("axis"))) for e in r.findall("translation")))
    defaults = {e.get("name", ""): float(e.get("default", "0")) for e in el.findall("coordinate")}
    locked = {e.get("name", ""): float(e.get("default", "0")) for e in el.findall("coordinate")
              if e.get("locked") == "true"}
    approx = tuple(Approximation(e.get("joint", ""), e.get("kind", ""), tuple(e.get("coordinates", "").split()),
                                 e.get("detail", ""), float(e.get("max_marker_mm", "0")), e.get("marker", ""),
                                 float(e.get("bound_mm", "0")), tuple(e.get("markers", "").split()),
                                 float(e.get("one_mm")) if e.get("one_mm") else None)
                   for e in el.findall("approximation"))
    dropped = tuple(e.get("coordinate", "") for e in el.findall("dropped"))
    bodies = {e.get("name", ""): X(e) for e in el.findall("body")}
    body_scale = {e.get("name", ""): float(e.get("scale", "1")) for e in el.findall("body")}
    ratios = {e.get("name", ""): float(e.get("ratio", "1")) for e in el.findall("coordinate") if e.get("ratio")}
    mixes = {e.get("name", ""): Mix(e.get("plus", ""), float(e.get("times", "0")), e.get("coupled", ""),
                                    *xml_floats(e.get("range", "0 0"))) for e in el.findall("coordinate")
             if e.get("plus")}
    gimbals = tuple((tuple(e.get("coordinates", "").split()), tuple(e.get("bodies", "").split()))
                    for e in el.findall("gimbal"))
    t = el.find("together")
    together = None if t is None else Together(float(t.get("max_marker_mm", "0")), t.get("marker", ""),
                                               float(t.get("mean_mm", "0")), int(t.get("poses", "0")))
    # (a URDF written before the flag was kept: every coordinate with a finite range clamped, as it was exported)
    clamped = tuple(e.get("name", "") for e in el.findall("coordinate") if e.get("clamped", "true") == "true")
    root_names = {e.get("coordinate", ""): e.get("source", "") for e in el.findall("root_name")}
    gravity = tuple(xml_floats(el.get("gravity"))) if el.get("gravity") else (0.0, -9.80665, 0.0)  # y up before
    return OsimInfo(el.get("source", ""), root, locked, defaults, approx, dropped, bodies, body_scale, ratios,
                    together, clamped, root_names, gravity, mixes, gimbals)  # type: ignore[arg-type]


def with_locked(model, settings):
    """`settings` with the model's locked OpenSim coordinates added to Settings.lock (those the settings
    already lock keep their values)."""
    from dataclasses import replace

    info = osim_info(model)
    if info is None or not info.locked:
        return settings
    have = dict(settings.lock)
    merged = {**{k: v for k, v in info.locked.items() if k in set(model.dof_names)}, **have}
    return replace(settings, lock=tuple(sorted(merged.items())))


def with_gimbals(model, settings):
    """`settings` with the axes of the model's gimbals (OsimInfo.gimbals: hinges the source chains about one centre
    through light bodies without markers, an angle convention for one ball) held at the model's (Settings.hold_axes),
    where the settings hold axes automatically and free them at all.  Left free, MoBL-ARMS's three shoulder hinges
    trade their axes through the two markerless bodies: a simulated arm's elv_angle axis turned 81 deg, the shoulder
    angles 50-73 deg RMS from the truth; held, 3.6-13.5 deg (docs/benchmarks.md)."""
    from dataclasses import replace

    info = osim_info(model)
    if info is None or not info.gimbals or not settings.auto_hold or "axis" not in settings.free:
        return settings
    locked = {n for n, _ in settings.lock}
    add = tuple(c for coords, _ in info.gimbals for c in coords
                if c in set(model.dof_names) and c not in locked and c not in settings.hold_axes)
    return replace(settings, hold_axes=settings.hold_axes + add) if add else settings


def gimbal_text(info: OsimInfo | None, held: Collection[str]) -> str:
    """Why the gimbals' axes among `held` are held (the summary's `axes held` line), or ''."""
    parts = [f"{', '.join(c for c in coords if c in held)} turn about one centre through {', '.join(bodies)} (light, "
             "no markers): one ball in the source's angle convention, not axes to calibrate"
             for coords, bodies in (info.gimbals if info is not None else ()) if any(c in held for c in coords)]
    return "; ".join(parts)


def import_summary(info: OsimInfo) -> list[str]:
    """What a calibration's note says of an imported model, one clause each: the joints approximated (each joint's
    largest marker effect), their effect together where markers lie below several, the other trees on ground left
    out, a ground joint made a floating base."""
    every = info.approximations
    approx = [a for a in every if a.kind not in NO_MARKER_EFFECT]
    left = [a.joint for a in every if a.kind == LEFT_OUT]
    floating = [a.joint for a in every if a.kind == FLOATING]
    said = [f"{len(approx)} joints approximated (" + ", ".join(
        f"{a.joint} {a.max_marker_mm:.1f} mm" if a.one_mm is None else
        f"{a.joint} {a.one_mm:.1f} mm one coordinate at a time, {a.max_marker_mm:.0f} at the ranges' ends "
        f"together" for a in approx) + ")"] if approx else []
    t = info.together
    said += [f"together up to {t.max_marker_mm:.0f} mm at {t.marker}, below several of them"] if t is not None else []
    said += [f"other trees on ground left out ({', '.join(left)})"] if left else []
    said += [f"its ground joint {floating[0]} made a floating base (the root's pose fitted in every frame)"
             ] if floating else []
    return said


def approximation_table(info: OsimInfo) -> str:
    """One line per approximated joint (for `calibrate inspect MODEL.osim`)."""
    if not info.approximations:
        return "  every joint imported exactly"
    lines = ["  " + a.text() for a in info.approximations]
    return "\n".join(lines + (["  " + info.together.text()] if info.together is not None else []))


def root_coordinates(info: OsimInfo, root_translation: np.ndarray, root_quaternion: np.ndarray,
                     root_scale: float = 1.0) -> dict[str, np.ndarray]:
    """OpenSim's ground-joint coordinates (rad, m) of root poses (n, 3) and quaternions (n, 4; x, y, z, w)
    of the root segment.  The rotation axes must be coordinate axes (as in every OpenSim ground joint)."""
    rt = info.root
    if rt is None:
        raise ModelError(f"{info.source}: its ground joint is not three rotations and three translations of "
                         f"coordinates; cannot write its coordinates")
    letters = ""
    signs = []
    for name, a in rt.rotations:
        k = int(np.argmax(np.abs(a)))
        if abs(abs(a[k]) - 1) > 1e-9:
            raise ModelError(f"{info.source}: the ground joint's rotation axis for '{name}' is not a coordinate axis; "
                             f"cannot write its coordinates")
        letters += "XYZ"[k]
        signs.append(math.copysign(1.0, a[k]))
    Rm, tm = rt.child_offset[0], rt.child_offset[1] * root_scale
    RG = quat_matrices(np.asarray(root_quaternion, float))  # (n, 3, 3) root segment in lab
    Rf, tf = rt.parent_offset
    # X_FM = X_GF^-1 X_GB X_BM
    R_fm = np.einsum("ij,njk,kl->nil", Rf.T, RG, Rm)
    p_fm = np.einsum("ij,nj->ni", Rf.T, np.einsum("nij,j->ni", RG, tm) + np.asarray(root_translation, float) - tf)
    ang = matrix_eulers(R_fm, letters)  # intrinsic (body-fixed) sequence
    ang = np.unwrap(ang * np.array(signs), axis=0)
    T = np.array([a for _, a in rt.translations]).T
    tr = np.linalg.solve(T, p_fm.T).T
    out = {name: ang[:, k] for k, (name, _) in enumerate(rt.rotations)}
    out.update({name: tr[:, k] for k, (name, _) in enumerate(rt.translations)})
    return out


def fixed_flags(osim: str | os.PathLike[str], marker_set: str | os.PathLike[str] | None = None) -> dict[str, bool]:
    """Each marker's OpenSim `<fixed>` flag (false where unset, OpenSim's default): the .osim's own markers, then the
    MarkerSet file's, which replace those of the same name as the Scale tool's do.  OpenSim's marker placer moves the
    markers not fixed to where the static shows them and leaves the fixed ones where the model puts them; calibrate
    places every marker from the trials alike (its marker prior), which `calibrate inspect` says."""
    from calibrate.io.osim_read import xml_root

    out: dict[str, bool] = {}
    for path, what in ((osim, "an OpenSim model (.osim)"), (marker_set, "an OpenSim MarkerSet file (.xml)")):
        if path is None:
            continue
        root = xml_root(Path(path), what, what)
        for mk in root.iter("Marker"):
            if mk.get("name"):
                out[mk.get("name")] = (mk.findtext("fixed") or "").strip().lower() == "true"
    return out


__all__ = ["approximation_table", "fixed_flags", "gimbal_text", "import_summary", "osim_info", "root_coordinates",
           "with_gimbals", "with_locked"]
