"""Are the posterior standard deviations right?  z-scores of the identified parameters over simulated subjects.

For each subject (seed s = 0..N-1) a squat trial of models/human.urdf is simulated (1 mm noise,
F frames at 100 Hz) and calibrated with the default settings.  For every parameter the
calibration calls identified (``Calibration.changes``), its error against the simulator's truth is
divided by the posterior SD it reports:

* marker positions and ball/universal joint centres: their offset from the segment's origin (the
  parent segment's, for a centre), from the lab: the estimate's world positions (by Pinocchio, from
  the written subject URDF and the fitted motion) minus the true noise-free ones, each relative to
  its segment origin, turned into the estimated segment frame and averaged over frames; one z per
  coordinate against the reported per-coordinate SD (the SDs hold each segment frame's orientation,
  a gauge, as the comparison in the estimated frame does);
* hinge axes: the angle (median over frames, lab frame) between the calibrated and the true axis,
  over sqrt(σ₁² + σ₂²) of the two reported tangent SDs (so that E z² = 1 when the SDs are right);
* segment scales: (s − s_true) / σ.

Hinge centres are never identified (along the axis only the prior holds them), so none enter.  If
the SDs are right, the z-scores have RMS about 1 and about 95 % lie within 2 (the check: RMS in
[0.8, 1.25], at least 90 % within 2 SD).  Printed per group and per parameter kind, so that an
over- or under-confident group shows.

    python scripts/bench_uncertainty.py [--subjects 20] [--frames 150] [--sta-mm X] [--json]

`--sta-mm X` adds the simulator's soft-tissue artefact (each skin marker moved on its bone as a smooth function
of the adjacent joints' angles; `calibrate simulate --sta-mm`): the errors then include the artefact's bias.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "human.urdf"
RMS_RANGE = (0.8, 1.25)  # issue 18's check
WITHIN_2SD = 0.90


def world_geometry(model, params, motion) -> dict[str, np.ndarray]:
    """Per frame, by Pinocchio from the URDF calibrate writes for `params`: each segment's rotation
    (F, n_segments, 3, 3) and origin (F, n_segments, 3), marker positions (F, n_markers, 3), joint
    centres (F, n_joints, 3) and hinge axes in the lab (F, n_joints, 3; NaN for other joints)."""
    import pinocchio as pin

    from calibrate.model.model import load_model, write_model

    with tempfile.TemporaryDirectory() as d:
        path = write_model(model, Path(d) / "subject.urdf", params)
        subject = load_model(path)
    pm = subject.pin
    data = pm.createData()
    seg_f = [pm.getFrameId(s.name, pin.FrameType.BODY) for s in subject.segments]
    mk_f = [pm.getFrameId(m.name, pin.FrameType.BODY) for m in subject.markers]
    jc = [pm.getJointId(j.urdf_joints[0]) for j in subject.joints]
    hinge = {ji: subject.dofs[subject.dof_index(j.dofs[0])] for ji, j in enumerate(subject.joints) if j.kind == "hinge"}
    hinge_f = {ji: pm.getFrameId(d.name) for ji, d in hinge.items()}
    F = len(motion.times)
    out = {"R": np.zeros((F, len(seg_f), 3, 3)), "origin": np.zeros((F, len(seg_f), 3)),
           "markers": np.zeros((F, len(mk_f), 3)),
           "centres": np.zeros((F, len(jc), 3)), "axes": np.full((F, len(jc), 3), np.nan)}
    for f in range(F):
        q = subject.pin_configuration(motion.root_translation[f], motion.root_quaternion[f], motion.angles[f])
        pin.framesForwardKinematics(pm, data, q)
        out["R"][f] = [data.oMf[i].rotation for i in seg_f]
        out["origin"][f] = [data.oMf[i].translation for i in seg_f]
        out["markers"][f] = [data.oMf[i].translation for i in mk_f]
        out["centres"][f] = [data.oMi[i].translation for i in jc]
        for ji, d in hinge.items():
            out["axes"][f, ji] = data.oMf[hinge_f[ji]].rotation @ d.axis
    return out


def one_subject(model, frames: int, seed: int, sta_mm: float = 0.0) -> list[dict]:
    """Calibrate one simulated subject; one row per z-score of an identified parameter."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.simulation.simulate import simulate_squats

    sim = simulate_squats(model, frames=frames, noise_mm=1.0, seed=seed, sta_mm=sta_mm)
    cal = calibrate(model, sim.trial)
    est = world_geometry(cal.model, cal.params, cal.motion)
    true = world_geometry(sim.model, sim.truth, sim.motion)
    m = cal.model

    def offset_error(x_est: np.ndarray, x_true: np.ndarray, seg: int) -> np.ndarray:
        """Error (mm) of a point's offset from segment `seg`'s origin, in that segment's estimated
        frame, averaged over frames: what the parameter is (positions relative to the segment frame)."""
        d = (x_est - est["origin"][:, seg]) - (x_true - true["origin"][:, seg])
        return 1000 * np.einsum("fji,fj->i", est["R"][:, seg], d) / len(d)

    # Offsets of every marker and joint centre in its segment (a centre: in its parent).
    errors: dict[str, np.ndarray] = {}
    seg_of: dict[str, int] = {}
    for k, mk in enumerate(m.markers):
        si = m.segment_index(mk.segment)
        errors[f"marker[{mk.name}]"] = offset_error(est["markers"][:, k], sim.clean_markers[:, k], si)
        seg_of[f"marker[{mk.name}]"] = si
    for ji, j in enumerate(m.joints):
        si = m.segment_index(j.parent)
        errors[f"centre[{j.name}]"] = offset_error(est["centres"][:, ji], sim.clean_centres[:, ji], si)
        seg_of[f"centre[{j.name}]"] = si
    # Gauges (Problem.gauge_constraints): a segment frame may turn against its contents (the root's
    # also shift) with no effect on the data.  The SDs are those of the contents with that turn
    # held (the prior-weighted net rotation of its markers, joint centres and child hinge axes about
    # the origin, and for the root their mean shift, fixed), so the errors are taken alike: per gauge
    # segment, less the rigid motion (turn about its origin; the root: and shift; a hinge's child:
    # turn about the hinge axis) that best explains its contents' errors, in the same weights.
    pr = cal.settings.priors
    for si, kind in _gauges(cal, sim.trial):
        keys = [k for k, s_ in seg_of.items() if s_ == si]
        if not keys:
            continue
        x = [_offset(cal, k) for k in keys]  # m, estimated segment frame
        e = [errors[k] / 1000 for k in keys]
        w = [1 / (pr.marker if k.startswith("marker[") else pr.centre) for k in keys]
        shifts = [True] * len(keys)
        for j in m.joints:  # child hinge axes: unit vectors, turned but not shifted
            if j.parent == m.segments[si].name and j.kind == "hinge":
                ji = m.joint_index(j.name)
                a_est, a_true = est["axes"][:, ji], true["axes"][:, ji]
                a_true = a_true * np.sign(np.sum(a_est * a_true, axis=1))[:, None]
                x.append(np.einsum("fji,fj->i", est["R"][:, si], a_est) / len(a_est))
                e.append(np.einsum("fji,fj->i", est["R"][:, si], a_est - a_true) / len(a_est))
                w.append(1 / pr.axis)
                shifts.append(False)
        x, e, w = np.array(x), np.array(e), np.repeat(w, 3)
        cols = []  # d e_i / d (rotation ω, shift t): e_i ≈ ω × x_i + t
        if kind == "axis":
            j = next(j for j in m.joints if j.child == m.segments[si].name)
            a = cal.params.axis[m.dof_index(j.dofs[-1])]
            cols.append(np.cross(a / np.linalg.norm(a), x))
        else:
            cols += [np.cross(u, x) for u in np.eye(3)]
        if kind == "rigid":
            cols += [np.outer(shifts, u) for u in np.eye(3)]
        A = np.stack([c.ravel() for c in cols], axis=1)
        coef, *_ = np.linalg.lstsq(w[:, None] * A, w * e.ravel(), rcond=None)
        for k, r in zip(keys, (e.ravel() - A @ coef).reshape(-1, 3), strict=False):
            errors[k] = 1000 * r
    rows = []

    def add(group: str, name: str, err: float, sd: float, unit: str) -> None:
        rows.append({"seed": seed, "group": group, "name": name, "error": float(err), "sd": float(sd),
                     "z": float(err / sd), "unit": unit})

    for c in cal.changes:
        if not c.identified or not np.all(np.isfinite(c.std)):
            continue
        group, name = c.name.split("[", 1)[0], c.name.split("[", 1)[1][:-1]
        if group == "centre" and m.joints[m.joint_index(name)].kind == "hinge":
            continue  # never identified (along the axis only the prior holds it)
        if group in ("marker", "centre"):
            for i, axis in enumerate("xyz"):
                add(group, f"{name}.{axis}", errors[c.name][i], c.std[i], "mm")
        elif group == "axis":
            dof = m.dofs[m.dof_index(name)]
            ji = m.joint_index(dof.joint)
            if m.joints[ji].kind != "hinge":
                continue  # universal joints' axes: no lab reference here
            cos = np.abs(np.sum(est["axes"][:, ji] * true["axes"][:, ji], axis=1)).clip(0, 1)
            add("axis", name, float(np.degrees(np.median(np.arccos(cos)))), float(np.sqrt(np.sum(c.std**2))), "deg")
        elif group == "scale":
            si = m.segment_index(name)
            add("scale", name, cal.params.scale[si] - sim.truth.scale[si], c.std[0], "fraction")
    return rows


def _offset(cal, key: str) -> np.ndarray:
    """A marker's or joint centre's calibrated position in its segment (a centre: its parent), m."""
    m, P = cal.model, cal.params
    name = key.split("[", 1)[1][:-1]
    if key.startswith("marker["):
        k = m.marker_index(name)
        return P.scale[m.segment_index(m.markers[k].segment)] * P.marker[k]
    ji = m.joint_index(name)
    return P.scale[m.segment_index(m.joints[ji].parent)] * P.centre[ji]


def _gauges(cal, trial) -> list[tuple[int, str]]:
    """The calibration's gauge segments (segment index, 'rigid' | 'rotation' | 'axis'), as its
    Problem finds them for its settings."""
    from calibrate.model.kinematics import build_kinematics
    from calibrate.problem.problem import Problem
    from calibrate.solve.ik import marker_columns

    problem = Problem(cal.model, marker_columns(cal.model, trial), cal.settings, build_kinematics(cal.model))
    return list(problem._gauges)


def _stats(z: np.ndarray) -> dict:
    return {"n": int(z.size), "rms_z": float(np.sqrt(np.mean(z**2))) if z.size else float("nan"),
            "within_2sd": float(np.mean(np.abs(z) <= 2)) if z.size else float("nan"),
            "mean_z": float(np.mean(z)) if z.size else float("nan")}


def summarise(rows: list[dict]) -> dict:
    """Pooled, per group, per subject; the parameters whose z are largest (RMS over subjects)."""
    z = np.array([r["z"] for r in rows])
    out = {"all": _stats(z)}
    out["groups"] = {g: _stats(np.array([r["z"] for r in rows if r["group"] == g]))
                     for g in ("centre", "axis", "marker", "scale")}
    out["subjects"] = {int(s): _stats(np.array([r["z"] for r in rows if r["seed"] == s]))
                       for s in sorted({r["seed"] for r in rows})}
    by: dict[str, list[float]] = {}
    for r in rows:
        by.setdefault(f"{r['group']}[{r['name']}]", []).append(r["z"])
    worst = sorted(by, key=lambda k: -float(np.mean(np.square(by[k]))))[:12]
    out["worst"] = [{"name": k, "rms_z": float(np.sqrt(np.mean(np.square(by[k])))), "n": len(by[k])} for k in worst]
    a = out["all"]
    out["pass"] = bool(RMS_RANGE[0] <= a["rms_z"] <= RMS_RANGE[1] and a["within_2sd"] >= WITHIN_2SD)
    return out


def run(subjects: int, frames: int, progress=None, sta_mm: float = 0.0) -> dict:
    """The benchmark: `subjects` simulated subjects (seeds 0..subjects-1) of `frames` frames, with the simulator's
    soft-tissue artefact at `sta_mm` (0: none)."""
    from calibrate.model.model import load_model

    model = load_model(MODEL)
    rows: list[dict] = []
    for seed in range(subjects):
        rows.extend(one_subject(model, frames, seed, sta_mm))
        if progress is not None:
            progress(f"bench_uncertainty: subject {seed + 1}/{subjects} done")
    return {"subjects": subjects, "frames": frames, "noise_mm": 1.0, "sta_mm": sta_mm, "rows": rows,
            "summary": summarise(rows)}


def print_tables(out: dict) -> None:
    s = out["summary"]
    sta = f", soft-tissue artefact {out['sta_mm']:g} mm" if out.get("sta_mm") else ""
    print(f"posterior SDs vs errors: {out['subjects']} simulated subjects, {out['frames']} frames of squats, "
          f"1 mm noise{sta} ({out['date']}, {out['machine']})")
    print(f"  {'group':8s} {'n':>6s} {'RMS z':>7s} {'mean z':>7s} {'|z|<=2':>7s}")
    for g, st in [("all", s["all"]), *s["groups"].items()]:
        if st["n"]:
            print(f"  {g:8s} {st['n']:6d} {st['rms_z']:7.2f} {st['mean_z']:+7.2f} {100 * st['within_2sd']:6.1f}%")
    print(f"\n  check: RMS z in [{RMS_RANGE[0]}, {RMS_RANGE[1]}] and >= {100 * WITHIN_2SD:.0f} % within 2 SD: "
          + ("PASS" if s["pass"] else "FAIL"))
    print("\n  per subject: " + ", ".join(f"{k}: {v['rms_z']:.2f}" for k, v in s["subjects"].items()))
    print("  largest z (RMS over subjects): " + ", ".join(f"{w['name']} {w['rms_z']:.1f}" for w in s["worst"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subjects", type=int, default=20, help="simulated subjects, seeds 0..N-1 (default 20)")
    ap.add_argument("--frames", type=int, default=150, help="frames per trial (default 150)")
    ap.add_argument("--sta-mm", type=float, default=0.0,
                    help="the simulator's soft-tissue artefact level (calibrate simulate --sta-mm; default 0: none)")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    a = ap.parse_args()
    if a.subjects < 1 or a.frames < 100 or a.sta_mm < 0:
        sys.exit("bench_uncertainty: --subjects must be at least 1, --frames at least 100 and --sta-mm at least 0")
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_calibrate import machine

    out = run(a.subjects, a.frames, progress=lambda msg: print(msg, file=sys.stderr, flush=True), sta_mm=a.sta_mm)
    mc = machine()
    out.update({"date": datetime.date.today().isoformat(), "machine": f"{mc['cpu']}, {mc['cores']} cores"})
    if a.json:
        print(json.dumps(out, default=lambda v: None if isinstance(v, float) and math.isnan(v) else v))
    else:
        print_tables(out)


if __name__ == "__main__":
    main()
