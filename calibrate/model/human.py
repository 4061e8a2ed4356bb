"""Parametric full-body human model (height, mass) written as a calibrate URDF.

Geometry: every segment frame sits at the segment's proximal joint centre and is
parallel to the lab frame in the neutral pose (standing, arms at the sides, thumbs
forward): x anterior, y left, z superior.  Landmark positions are given for a
1.75 m reference adult and scaled by ``height / 1.75``.

Inertial properties: de Leva P. (1996) "Adjustments to Zatsiorsky-Seluyanov's
segment inertia parameters", J. Biomech. 29(9):1223-1230, Table 4 (males):
mass fraction, centre-of-mass position along the segment and radii of gyration
(sagittal, transverse, longitudinal) as fractions of segment length.  The torso
is the composite of de Leva's upper and middle trunk (parallel-axis theorem); the
pelvis is his lower trunk.  Talus/calcaneus split the foot 10/90, ulna/radius split
the forearm 50/50.

Joint axes of the ankle complex follow OpenSim's gait2392 model (Delp 1990,
after Inman 1976), converted to this frame; all angles are zero in the neutral pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import numpy as np

from ..io.text import fmt_float, fmt_vec

REFERENCE_HEIGHT = 1.75  # m; the landmark table below is for this stature

GIRDLE_MASS = 0.005  # of the body's mass, each clavicle segment of build_human_urdf(girdle=True): an assumption (the
# clavicle, the shoulder blade and some of the muscle that moves with them); de Leva has no girdle segment


@dataclass(frozen=True)
class DeLeva:
    """One de Leva (1996) row: mass fraction, CoM fraction from the proximal end, radii."""

    mass: float  # fraction of body mass
    com: float  # fraction of segment length from the proximal endpoint
    r_sag: float  # radius of gyration about the antero-posterior axis / length
    r_tra: float  # ... about the medio-lateral axis / length
    r_lon: float  # ... about the longitudinal axis / length


# de Leva 1996, Table 4, males. Percentages converted to fractions.
DE_LEVA = {
    "head": DeLeva(0.0694, 0.5002, 0.303, 0.315, 0.261),  # VERT-CERV, from VERT
    "upper_trunk": DeLeva(0.1596, 0.5066, 0.505, 0.320, 0.465),  # CERV-XYPH, from CERV
    "middle_trunk": DeLeva(0.1633, 0.4502, 0.482, 0.383, 0.468),  # XYPH-OMPH, from XYPH
    "lower_trunk": DeLeva(0.1117, 0.6115, 0.615, 0.551, 0.587),  # OMPH-MIDH, from OMPH
    "upper_arm": DeLeva(0.0271, 0.5772, 0.285, 0.269, 0.158),  # SJC-EJC
    "forearm": DeLeva(0.0162, 0.4574, 0.276, 0.265, 0.121),  # EJC-WJC
    "hand": DeLeva(0.0061, 0.7900, 0.628, 0.513, 0.401),  # WJC-MET3
    "thigh": DeLeva(0.1416, 0.4095, 0.329, 0.329, 0.149),  # HJC-KJC
    "shank": DeLeva(0.0433, 0.4459, 0.255, 0.249, 0.103),  # KJC-LMAL
    "foot": DeLeva(0.0137, 0.4415, 0.257, 0.245, 0.124),  # HEEL-TTIP
}
# de Leva's upper/middle trunk lengths (mm, males), used to combine them into one torso.
UPPER_TRUNK_MM, MIDDLE_TRUNK_MM = 242.1, 215.5

# Neutral-pose landmarks of the 1.75 m reference (metres, lab frame, floor at z = 0).
# Right side only (y < 0); the left side is the mirror image y -> -y.
RIGHT_LANDMARKS = {
    "hip": (0.0, -0.088, 0.930),
    "knee": (0.0, -0.090, 0.506),
    "ankle": (0.0, -0.090, 0.070),
    "subtalar": (-0.049, -0.098, 0.028),
    "heel": (-0.085, -0.090, 0.030),
    "toe_tip": (0.175, -0.090, 0.030),
    "shoulder": (-0.010, -0.170, 1.410),
    "sternoclavicular": (0.040, -0.025, 1.425),  # girdle=True only: behind and beside the jugular notch
    "elbow": (-0.010, -0.170, 1.127),
    "radial_head": (-0.010, -0.185, 1.117),
    "ulnar_head": (-0.025, -0.160, 0.860),
    "wrist": (-0.010, -0.170, 0.857),
    "hand_end": (-0.005, -0.175, 0.770),
}
MIDLINE_LANDMARKS = {
    "pelvis": (0.0, 0.0, 0.930),  # mid-point of the hip joint centres
    "lumbar": (-0.040, 0.0, 1.050),
    "neck": (-0.040, 0.0, 1.500),
    "vertex": (0.0, 0.0, 1.750),
}

# Plug-in Gait markers: label -> (segment, neutral-pose position). Right side and midline;
# left-side labels are mirrored from the right ones (R -> L, y -> -y).
_MARKERS_R = {
    "RASI": ("pelvis", (0.055, -0.122, 1.004)),
    "RPSI": ("pelvis", (-0.125, -0.045, 1.020)),
    "RTHI": ("femur", (0.010, -0.163, 0.676)),
    "RKNE": ("femur", (0.0, -0.145, 0.506)),
    "RTIB": ("tibia", (0.010, -0.145, 0.244)),
    "RANK": ("tibia", (-0.010, -0.130, 0.065)),
    "RHEE": ("calcn", (-0.095, -0.090, 0.040)),
    "RTOE": ("calcn", (0.135, -0.085, 0.030)),
    "RFHD": ("head", (0.095, -0.050, 1.670)),
    "RBHD": ("head", (-0.090, -0.050, 1.700)),
    "RSHO": ("torso", (-0.010, -0.190, 1.455)),
    "RBAK": ("torso", (-0.130, -0.080, 1.360)),
    "RUPA": ("humerus", (-0.010, -0.215, 1.270)),
    "RELB": ("humerus", (-0.010, -0.218, 1.127)),  # 48 mm lateral of the elbow: measured subjects 47-55 (1.5-1.8 m)
    "RFRM": ("ulna", (-0.045, -0.165, 1.030)),
    "RWRA": ("radius", (0.025, -0.170, 0.852)),
    "RWRB": ("radius", (-0.030, -0.170, 0.852)),
    "RFIN": ("hand", (0.010, -0.185, 0.775)),
}
_MARKERS_MID = {
    "C7": ("torso", (-0.095, 0.0, 1.500)),
    "T10": ("torso", (-0.125, 0.0, 1.290)),
    "CLAV": ("torso", (0.060, 0.0, 1.440)),
    "STRN": ("torso", (0.105, 0.0, 1.280)),
}


def _unit(v) -> tuple[float, float, float]:
    a = np.asarray(v, dtype=float)
    a = a / np.linalg.norm(a)
    return (float(a[0]), float(a[1]), float(a[2]))


# Right-side hinge axes in the parent frame, positive sense as named.
_PRONATION_R = _unit(np.subtract(RIGHT_LANDMARKS["radial_head"], RIGHT_LANDMARKS["ulnar_head"]))
_AXES_R = {
    "knee": _unit((0.0, 0.9994, 0.035)),  # flexion +
    "ankle": _unit((-0.10501355, -0.97912632, -0.17402245)),  # dorsiflexion + (gait2392)
    "subtalar": _unit((0.78717961, 0.12094949, 0.60474746)),  # inversion + (gait2392)
    "elbow": _unit((-0.02, -0.995, 0.10)),  # flexion +, carrying angle
    "radioulnar": _PRONATION_R,  # pronation +
}


def _mirror_point(p) -> tuple[float, float, float]:
    return (p[0], -p[1], p[2])


def _mirror_axis(a) -> tuple[float, float, float]:
    """Axis of the mirrored rotation with the same anatomical sign (axial vector)."""
    return (-a[0], a[1], -a[2])


@dataclass
class _Seg:
    name: str
    origin: np.ndarray  # neutral-pose world position of the segment frame (m)
    mass: float
    com: np.ndarray  # world position of the centre of mass
    inertia: np.ndarray  # (3,) principal moments about the CoM, segment axes (kg m^2)
    visual: str = ""  # URDF <geometry> content, placed at `visual_at` (world)
    visual_at: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class _Joint:
    name: str  # anatomical joint name; URDF joints are name or name_<dof>
    parent: str
    child: str
    dofs: list[tuple[str, tuple[float, float, float], float, float]]  # (suffix, axis, lo, hi)


def build_human_urdf(height: float = REFERENCE_HEIGHT, mass: float = 75.0, name: str = "human",
                     girdle: bool = False) -> str:
    """Return the URDF text of a full-body model for a subject of `height` (m) and `mass` (kg).

    38 degrees of freedom with the free-flyer the loader adds to the pelvis; Plug-in Gait
    markers as fixed leaf links.  `girdle`: a shoulder girdle on each side (models/human_girdle.urdf,
    42 DoF): a clavicle segment from a sternoclavicular universal joint on the torso (protraction about
    the vertical, then elevation about the clavicle's anterior axis, ISB's order) carrying the shoulder's
    ball at its lateral end and the acromion marker (xSHO), which rides with the shoulder blade when the
    arm rises instead of on the thorax.  Its mass (GIRDLE_MASS of the body's each) is taken from the
    torso's.  Raises ValueError for heights outside 0.5-2.5 m or masses outside 5-300 kg.
    """
    if not (0.5 <= height <= 2.5):
        raise ValueError(f"height must be 0.5-2.5 m, got {height}")
    if not (5.0 <= mass <= 300.0):
        raise ValueError(f"mass must be 5-300 kg, got {mass}")
    k = height / REFERENCE_HEIGHT

    def P(p) -> np.ndarray:
        return k * np.asarray(p, dtype=float)

    pts: dict[str, np.ndarray] = {n: P(p) for n, p in MIDLINE_LANDMARKS.items()}
    for side, sgn in (("r", 1.0), ("l", -1.0)):
        for n, p in RIGHT_LANDMARKS.items():
            pts[f"{n}_{side}"] = P(p if sgn > 0 else _mirror_point(p))

    segs: list[_Seg] = []

    def long_segment(seg: str, row: str, prox: np.ndarray, dist: np.ndarray, origin: np.ndarray,
                     frac: float = 1.0, radius: float = 0.04, lon_axis: int = 2) -> None:
        d = DE_LEVA[row]
        length = float(np.linalg.norm(dist - prox))
        m = mass * d.mass * frac
        radii = [d.r_sag, d.r_tra, d.r_lon]
        if lon_axis == 0:  # foot: longitudinal axis is x
            radii = [d.r_lon, d.r_tra, d.r_sag]
        inertia = m * (np.asarray(radii) * length) ** 2
        vis = f'<cylinder radius="{fmt_float(radius * k)}" length="{fmt_float(length)}"/>'
        if lon_axis == 0:
            vis = f'<box size="{fmt_vec((length, 0.09 * k, 0.05 * k))}"/>'
        segs.append(_Seg(seg, origin, m, prox + d.com * (dist - prox), inertia, vis, 0.5 * (prox + dist)))

    # Pelvis (de Leva lower trunk, measured from OMPH downwards to MIDH).
    pel = DE_LEVA["lower_trunk"]
    pel_len = float(pts["lumbar"][2] - pts["pelvis"][2])
    omph = pts["pelvis"] + np.array([0.0, 0.0, pel_len])
    segs.append(_Seg("pelvis", pts["pelvis"], mass * pel.mass,
                     omph + pel.com * (pts["pelvis"] - omph),
                     mass * pel.mass * (np.array([pel.r_sag, pel.r_tra, pel.r_lon]) * pel_len) ** 2,
                     f'<box size="{fmt_vec(k * np.array([0.16, 0.26, 0.12]))}"/>',
                     pts["pelvis"] + k * np.array([-0.03, 0.0, 0.05])))

    # Torso = de Leva upper + middle trunk combined (parallel-axis theorem), CERV at the neck joint.
    up, mid = DE_LEVA["upper_trunk"], DE_LEVA["middle_trunk"]
    t_len = float(pts["neck"][2] - pts["lumbar"][2])
    f_up = UPPER_TRUNK_MM / (UPPER_TRUNK_MM + MIDDLE_TRUNK_MM)
    l_up, l_mid = f_up * t_len, (1 - f_up) * t_len
    m_up, m_mid = mass * up.mass, mass * mid.mass
    c_up = pts["neck"] - np.array([0, 0, up.com * l_up])
    c_mid = pts["neck"] - np.array([0, 0, l_up + mid.com * l_mid])
    m_t = m_up + m_mid
    c_t = (m_up * c_up + m_mid * c_mid) / m_t
    inertia_t = np.zeros(3)
    for m_i, c_i, row, L in ((m_up, c_up, up, l_up), (m_mid, c_mid, mid, l_mid)):
        own = m_i * (np.array([row.r_sag, row.r_tra, row.r_lon]) * L) ** 2
        dz = float(c_i[2] - c_t[2])
        inertia_t += own + m_i * np.array([dz * dz, dz * dz, 0.0])
    segs.append(_Seg("torso", pts["lumbar"], m_t, c_t, inertia_t,
                     f'<box size="{fmt_vec(k * np.array([0.20, 0.32, 0.45]))}"/>',
                     0.5 * (pts["lumbar"] + pts["neck"])))
    long_segment("head", "head", pts["vertex"], pts["neck"], pts["neck"], radius=0.0)
    segs[-1].visual = f'<sphere radius="{fmt_float(0.10 * k)}"/>'
    segs[-1].visual_at = pts["neck"] + k * np.array([0.03, 0.0, 0.13])

    if girdle:  # each clavicle's mass out of the torso's (its inertia in proportion): the body's total kept
        torso = segs[1]
        m_g = GIRDLE_MASS * mass
        torso.inertia = torso.inertia * (torso.mass - 2 * m_g) / torso.mass
        torso.mass -= 2 * m_g
        for s in ("r", "l"):
            sc, gh = pts[f"sternoclavicular_{s}"], pts[f"shoulder_{s}"]
            length = float(np.linalg.norm(gh - sc))
            segs.append(_Seg(f"clavicle_{s}", sc, m_g, 0.5 * (sc + gh),
                             m_g * np.array([0.3, 0.1, 0.3]) ** 2 * length**2,  # a rod along y
                             f'<box size="{fmt_vec((0.03 * k, length, 0.03 * k))}"/>', 0.5 * (sc + gh)))

    for s in ("r", "l"):
        g = {n: pts[f"{n}_{s}"] for n in RIGHT_LANDMARKS}
        long_segment(f"humerus_{s}", "upper_arm", g["shoulder"], g["elbow"], g["shoulder"], radius=0.04)
        long_segment(f"ulna_{s}", "forearm", g["elbow"], g["wrist"], g["elbow"], frac=0.5, radius=0.022)
        long_segment(f"radius_{s}", "forearm", g["elbow"], g["wrist"], g["radial_head"], frac=0.5, radius=0.022)
        long_segment(f"hand_{s}", "hand", g["wrist"], g["hand_end"], g["wrist"], radius=0.03)
        long_segment(f"femur_{s}", "thigh", g["hip"], g["knee"], g["hip"], radius=0.06)
        long_segment(f"tibia_{s}", "shank", g["knee"], g["ankle"], g["knee"], radius=0.045)
        foot = DE_LEVA["foot"]
        m_talus = 0.1 * mass * foot.mass
        segs.append(_Seg(f"talus_{s}", g["ankle"], m_talus, g["ankle"].copy(),
                         np.full(3, 0.4 * m_talus * (0.02 * k) ** 2),
                         f'<sphere radius="{fmt_float(0.02 * k)}"/>', g["ankle"].copy()))
        long_segment(f"calcn_{s}", "foot", g["heel"], g["toe_tip"], g["subtalar"], frac=0.9, lon_axis=0)

    origin = {sg.name: sg.origin for sg in segs}
    d = math.radians
    joints: list[_Joint] = [
        _Joint("lumbar", "pelvis", "torso", [
            ("flexion", (0.0, 1.0, 0.0), d(-30), d(90)),
            ("bending", (1.0, 0.0, 0.0), d(-40), d(40)),
            ("rotation", (0.0, 0.0, 1.0), d(-45), d(45))]),
        _Joint("neck", "torso", "head", [
            ("flexion", (0.0, 1.0, 0.0), d(-60), d(70)),
            ("bending", (1.0, 0.0, 0.0), d(-45), d(45)),
            ("rotation", (0.0, 0.0, 1.0), d(-80), d(80))]),
    ]
    for s in ("r", "l"):
        mir = (lambda a: a) if s == "r" else _mirror_axis
        x = mir((1.0, 0.0, 0.0))
        z = mir((0.0, 0.0, 1.0))
        joints += [
            _Joint(f"hip_{s}", "pelvis", f"femur_{s}", [
                ("flexion", (0.0, -1.0, 0.0), d(-30), d(125)),
                ("adduction", x, d(-50), d(30)),
                ("rotation", z, d(-45), d(45))]),
            _Joint(f"knee_{s}", f"femur_{s}", f"tibia_{s}", [("", mir(_AXES_R["knee"]), d(-5), d(150))]),
            _Joint(f"ankle_{s}", f"tibia_{s}", f"talus_{s}", [("", mir(_AXES_R["ankle"]), d(-45), d(30))]),
            _Joint(f"subtalar_{s}", f"talus_{s}", f"calcn_{s}", [("", mir(_AXES_R["subtalar"]), d(-30), d(30))]),
        ]
        if girdle:
            joints.append(_Joint(f"sc_{s}", "torso", f"clavicle_{s}", [
                ("protraction", z, d(-30), d(30)),
                ("elevation", mir((-1.0, 0.0, 0.0)), d(-10), d(45))]))
        joints += [
            _Joint(f"shoulder_{s}", f"clavicle_{s}" if girdle else "torso", f"humerus_{s}", [
                ("flexion", (0.0, -1.0, 0.0), d(-60), d(180)),
                ("adduction", x, d(-180), d(40)),
                ("rotation", z, d(-90), d(90))]),
            _Joint(f"elbow_{s}", f"humerus_{s}", f"ulna_{s}", [("", mir(_AXES_R["elbow"]), d(-5), d(150))]),
            _Joint(f"radioulnar_{s}", f"ulna_{s}", f"radius_{s}",
                   [("", mir(_AXES_R["radioulnar"]), d(-90), d(90))]),
            _Joint(f"wrist_{s}", f"radius_{s}", f"hand_{s}", [
                ("flexion", x, d(-70), d(80)),
                ("deviation", (0.0, 1.0, 0.0), d(-25), d(35))]),
        ]

    markers: list[tuple[str, str, np.ndarray]] = []
    for label, (seg, p) in _MARKERS_MID.items():
        markers.append((label, seg, P(p)))
    for label, (seg, p) in _MARKERS_R.items():
        if label == "RBAK":  # Plug-in Gait's asymmetry marker: right side only
            markers.append((label, seg, P(p)))
        elif label == "RSHO" and girdle:
            markers.append((label, "clavicle_r", P(p)))
            markers.append(("L" + label[1:], "clavicle_l", P(_mirror_point(p))))
        elif seg in ("pelvis", "torso", "head"):
            markers.append((label, seg, P(p)))
            markers.append(("L" + label[1:], seg, P(_mirror_point(p))))
        else:
            markers.append((label, f"{seg}_r", P(p)))
            markers.append(("L" + label[1:], f"{seg}_l", P(_mirror_point(p))))
    order = {"pelvis": 0, "torso": 1, "head": 2, "clavicle_l": 3, "clavicle_r": 3}
    markers.sort(key=lambda m: (order.get(m[1], 3), m[1], m[0]))

    out: list[str] = [
        '<?xml version="1.0"?>',
        f"<!-- calibrate human model: height {height:g} m, mass {mass:g} kg.",
        "     Generated by scripts/make_human_model.py (calibrate.model.human); see docs/model-format.md.",
        "     Inertial data: de Leva (1996), J. Biomech. 29(9):1223-1230, Table 4 (males). -->",
        f"<robot name={quoteattr(name)}>",
        '  <material name="segment"><color rgba="0.80 0.72 0.62 1"/></material>',
        '  <material name="marker"><color rgba="0.95 0.95 0.20 1"/></material>',
    ]
    for sg in segs:
        com = sg.com - sg.origin
        vis = sg.visual_at - sg.origin
        out += [
            f'  <link name="{sg.name}">',
            "    <inertial>",
            f'      <origin xyz="{fmt_vec(com)}" rpy="0 0 0"/>',
            f'      <mass value="{fmt_float(sg.mass)}"/>',
            f'      <inertia ixx="{fmt_float(sg.inertia[0])}" ixy="0" ixz="0" iyy="{fmt_float(sg.inertia[1])}" '
            f'iyz="0" izz="{fmt_float(sg.inertia[2])}"/>',
            "    </inertial>",
            "    <visual>",
            f'      <origin xyz="{fmt_vec(vis)}" rpy="0 0 0"/>',
            f"      <geometry>{sg.visual}</geometry>",
            '      <material name="segment"/>',
            "    </visual>",
            "  </link>",
        ]
    for jt in joints:
        parent = jt.parent
        n = len(jt.dofs)
        for i, (suffix, axis, lo, hi) in enumerate(jt.dofs):
            jname = f"{jt.name}_{suffix}" if suffix else jt.name
            child = jt.child if i == n - 1 else f"{jname}_link"
            xyz = origin[jt.child] - origin[jt.parent] if i == 0 else np.zeros(3)
            if child != jt.child:  # massless connector of a multi-DoF joint
                out.append(f'  <link name="{child}"/>')
            out += [
                f'  <joint name="{jname}" type="revolute">',
                f'    <parent link="{parent}"/>',
                f'    <child link="{child}"/>',
                f'    <origin xyz="{fmt_vec(xyz)}" rpy="0 0 0"/>',
                f'    <axis xyz="{fmt_vec(axis)}"/>',
                f'    <limit lower="{fmt_float(lo)}" upper="{fmt_float(hi)}" effort="1000" velocity="20"/>',
                "  </joint>",
            ]
            parent = child
    for label, seg, p in markers:
        out += [
            f'  <link name="{label}">',
            f'    <visual><geometry><sphere radius="{fmt_float(0.007)}"/></geometry>'
            '<material name="marker"/></visual>',
            "  </link>",
            f'  <joint name="{label}_marker" type="fixed">',
            f'    <parent link="{seg}"/>',
            f'    <child link="{label}"/>',
            f'    <origin xyz="{fmt_vec(p - origin[seg])}" rpy="0 0 0"/>',
            "  </joint>",
        ]
    out.append("</robot>")
    return "\n".join(out) + "\n"
