"""Calibration settings from a TOML file (``calibrate ... --config calib.toml``).

Every key is optional; units are in the key names (mm, deg).  Example, with the defaults::

    free = ["scale", "centre", "axis", "marker"]   # parameter groups to calibrate
    noise_mm = 1.0          # marker noise SD: weights the marker residuals (given: kept, not learnt)
    learn_noise = true      # learn each marker's noise SD from the residuals (default unless noise_mm is given)
    loss = "linear"         # or "huber", "cauchy" (robust against marker outliers)
    loss_scale = 3.0        # robust-loss scale, in units of noise_mm
    max_iterations = 100
    ftol = 1e-6             # stop: relative cost decrease of a step below this
    atol = 0.5              # ... or absolute decrease below this (chi-square change of 1)
    seed = true             # start from MTB joint centres (false: from the base model)
    compile = true          # compile the per-frame function with the C compiler if present
    new_markers = true      # place trial markers the model does not know on segments and fit them
    outlier_sigmas = 6.0    # reject a marker in a frame whose error exceeds this many noise SDs (0: off)
    geodesic = true         # geodesic acceleration of the solver's steps (follows curved valleys)
    memory_mb = 200.0       # the frames' normal-equation blocks held at once (~170 kB per frame, full body);
                            # a longer trial's are formed chunk by chunk (bounded memory, a little more time)
    ahead = true            # the start's GIL-bound parts in a forked process on the other core (same results)
    still_weight = 0        # frames a still (static) trial counts as in all beside a moving one (0: every frame)
    moved_markers = false   # leave out a still trial's positions of markers the moving trials put elsewhere
    far_joints = true       # leave out a still trial's markers beyond a joint it holds where the moving trials never go
    hip_regression = "outside"  # hip centres by Harrington's regression from the pelvis markers: true, false,
                                # "auto" (where they end implausible), "outside" (outside the pelvis
                                # or on its midline)

    hold_axes = []          # hinge/universal DoFs whose axis stays the base model's (angles stay free)
    hold_centres = []       # joints whose centre keeps the base model's offset from its parent's markers (["back"])
    auto_hold = true        # also hold the axis of every coordinate the trial does not show moving
    segment_frames = "markers"  # joint angles in the frames the segments' markers put ("priors": the solve's);
                            # default: "markers" for an OpenSim model, "priors" for a URDF

    [priors]                # SDs of the pull towards the base model
    marker_mm = 20.0
    centre_mm = 20.0
    axis_deg = 10.0
    scale = 0.25            # SD of a segment's scale about the subject's size (the segments' mean scale)
    size = 0.25             # SD of the subject's size about the base model's (0: each segment's scale about 1)
    symmetry_scale = 0.05   # SD of a left/right difference of segment scales (0: off)
    symmetry_centre_mm = 20.0  # SD of a left/right difference of mirrored joint centres (0: off)
    width_mm = 5.0          # SD of a measured knee/ankle width's lateral distance (0: measurements not used)
    population_width_mm = 8.0  # ... and, none measured, about the base model's at the segment's scale (0: off)
    on_axis_mm = 10.0       # SD of KNE/ANK/ELB's distance from a held hinge axis through its centre (0: off)
    pair_axis_deg = 5.0     # SD of a knee/ankle/elbow axis's angle from the line of two markers straddling it (0: off)
    knee_landmark_mm = 1.0  # SD of a turning knee's centre from the axis line through its epicondyles or KNE (0: off)
    ankle_landmark_mm = 1.0  # SD of a turning ankle's centre from the axis line through its two malleoli (0: off)
    joint_marker_mm = 1.0   # SD of a joint-centre marker's offset from its centre (e.g. R_HJC; 0: an ordinary marker)
    held_centre_mm = 0.1    # SD of a held centre's offset from its parent's markers (hold_centres)

    [marker_noise_mm]       # per-marker noise SD where it differs from noise_mm (none by default)
    # RTHI = 3.0            # e.g. a wand marker on soft tissue counts 1/9 as much (OpenSim weight 1/9)

    [lock_deg]              # coordinates held at a value in every frame (none by default)
    # subtalar_r = 0.0      # e.g. what a two-marker foot cannot resolve
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import replace
from pathlib import Path

from ..errors import CalibrateError
from ..problem.settings import Priors, Settings

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

_TOP = {"free", "noise_mm", "loss", "loss_scale", "max_iterations", "ftol", "atol", "xtol", "gtol", "seed", "compile",
        "new_markers", "outlier_sigmas", "geodesic", "memory_mb", "priors", "marker_noise_mm", "lock_deg", "hold_axes",
        "hold_centres", "auto_hold", "segment_frames", "learn_noise", "ahead", "still_weight", "moved_markers",
        "far_joints", "hip_regression"}
_PRIORS = {"marker_mm", "centre_mm", "axis_deg", "scale", "size", "symmetry_scale", "symmetry_centre_mm", "width_mm",
           "population_width_mm", "on_axis_mm", "pair_axis_deg", "knee_landmark_mm", "ankle_landmark_mm",
           "joint_marker_mm", "held_centre_mm", "placeholder_mm"}


def settings_from_dict(data: dict, where: str = "settings", base: Settings | None = None) -> Settings:
    """Settings from a dict in the TOML layout (mm, deg); one-line CalibrateError on a bad key or value."""
    s = base or Settings()
    unknown = sorted(set(data) - _TOP)
    if unknown:
        raise CalibrateError(f"{where}: unknown setting '{unknown[0]}'; known: {', '.join(sorted(_TOP))}")
    pri = data.get("priors", {})
    if not isinstance(pri, dict):
        raise CalibrateError(f"{where}: 'priors' must be a table ([priors])")
    unknown = sorted(set(pri) - _PRIORS)
    if unknown:
        raise CalibrateError(f"{where}: unknown prior '{unknown[0]}'; known: {', '.join(sorted(_PRIORS))}")

    def num(d: dict, key: str, default: float) -> float:
        v = d.get(key, default)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise CalibrateError(f"{where}: '{key}' must be a number, got {v!r}")
        return float(v)

    priors = Priors(
        marker=num(pri, "marker_mm", 1000 * s.priors.marker) / 1000,
        centre=num(pri, "centre_mm", 1000 * s.priors.centre) / 1000,
        axis=math.radians(num(pri, "axis_deg", math.degrees(s.priors.axis))),
        scale=num(pri, "scale", s.priors.scale),
        size=num(pri, "size", s.priors.size),
        symmetry_scale=num(pri, "symmetry_scale", s.priors.symmetry_scale),
        symmetry_centre=num(pri, "symmetry_centre_mm", 1000 * s.priors.symmetry_centre) / 1000,
        width=num(pri, "width_mm", 1000 * s.priors.width) / 1000,
        population_width=num(pri, "population_width_mm", 1000 * s.priors.population_width) / 1000,
        on_axis=num(pri, "on_axis_mm", 1000 * s.priors.on_axis) / 1000,
        pair_axis=math.radians(num(pri, "pair_axis_deg", math.degrees(s.priors.pair_axis))),
        knee_landmark=num(pri, "knee_landmark_mm", 1000 * s.priors.knee_landmark) / 1000,
        ankle_landmark=num(pri, "ankle_landmark_mm", 1000 * s.priors.ankle_landmark) / 1000,
        joint_marker=num(pri, "joint_marker_mm", 1000 * s.priors.joint_marker) / 1000,
        held_centre=num(pri, "held_centre_mm", 1000 * s.priors.held_centre) / 1000,
        placeholder=num(pri, "placeholder_mm", 1000 * s.priors.placeholder) / 1000,
    )
    free = data.get("free", list(s.free))
    if isinstance(free, str) or not isinstance(free, list) or not all(isinstance(x, str) for x in free):
        raise CalibrateError(f"{where}: 'free' must be a list of group names, e.g. [\"centre\", \"marker\"]")
    for key in ("seed", "compile", "new_markers", "geodesic", "learn_noise"):
        if key in data and not isinstance(data[key], bool):
            raise CalibrateError(f"{where}: '{key}' must be true or false, got {data[key]!r}")
    it = data.get("max_iterations", s.max_iterations)
    if isinstance(it, bool) or not isinstance(it, int):
        raise CalibrateError(f"{where}: 'max_iterations' must be a whole number, got {it!r}")
    loss = data.get("loss", s.loss)
    def table(key: str, what: str, to_si, default: tuple) -> tuple:
        """A [key] table of name = number, in SI units, sorted by name; `default` if absent."""
        t = data.get(key, None)
        if t is None:
            return default
        if not isinstance(t, dict):
            raise CalibrateError(f"{where}: '{key}' must be a table ([{key}], {what})")
        return tuple(sorted((str(k), to_si(num(t, k, 0.0))) for k in t))

    marker_noise = table("marker_noise_mm", "label = SD in mm", lambda v: v / 1000, s.marker_noise)
    lock = table("lock_deg", "DoF = angle in degrees", math.radians, s.lock)
    hold = data.get("hold_axes", s.hold_axes)
    if not (isinstance(hold, (list, tuple)) and all(isinstance(x, str) for x in hold)):
        raise CalibrateError(f"{where}: 'hold_axes' must be a list of DoF names, e.g. [\"subtalar_r\"]")
    centres = data.get("hold_centres", s.hold_centres)
    if not (isinstance(centres, (list, tuple)) and all(isinstance(x, str) for x in centres)):
        raise CalibrateError(f"{where}: 'hold_centres' must be a list of joint names, e.g. [\"back\"]")
    auto_hold = data.get("auto_hold", s.auto_hold)
    if not isinstance(auto_hold, bool):
        raise CalibrateError(f"{where}: 'auto_hold' must be true or false, got {auto_hold!r}")
    # A noise stated by the user is kept (not learnt from the data) unless learn_noise says otherwise.
    learn = data.get("learn_noise", False if "noise_mm" in data else s.learn_noise)
    try:
        return replace(s, learn_noise=learn, free=tuple(free), noise=num(data, "noise_mm", 1000 * s.noise) / 1000,
                       loss=str(loss), loss_scale=num(data, "loss_scale", s.loss_scale), priors=priors,
                       max_iterations=it, ftol=num(data, "ftol", s.ftol), atol=num(data, "atol", s.atol),
                       xtol=num(data, "xtol", s.xtol),
                       gtol=num(data, "gtol", s.gtol), seed=data.get("seed", s.seed),
                       compile=data.get("compile", s.compile), new_markers=data.get("new_markers", s.new_markers),
                       outliers=num(data, "outlier_sigmas", s.outliers),
                       geodesic=data.get("geodesic", s.geodesic), memory_mb=num(data, "memory_mb", s.memory_mb),
                       marker_noise=marker_noise, lock=lock,
                       hold_axes=tuple(hold), hold_centres=tuple(centres), auto_hold=auto_hold,
                       ahead=data.get("ahead", s.ahead),
                       segment_frames=data.get("segment_frames", s.segment_frames),
                       still_weight=num(data, "still_weight", s.still_weight),
                       moved_markers=data.get("moved_markers", s.moved_markers),
                       far_joints=data.get("far_joints", s.far_joints),
                       hip_regression=data.get("hip_regression", s.hip_regression))
    except ValueError as e:
        raise CalibrateError(f"{where}: {e}") from None


def load_settings(path: str | os.PathLike[str], base: Settings | None = None) -> Settings:
    """Settings from a TOML file (see the module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrateError(f"{path}: no such config file; give a .toml file (see docs/calibration.md)")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CalibrateError(f"{path}: not valid TOML ({e})") from None
    return settings_from_dict(data, str(path), base)
