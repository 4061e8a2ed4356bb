#!/usr/bin/env python
"""calibrate against an expert's hand-scaling: the AddBiomechanics paper's expert data.

Werling et al. (2023, AddBiomechanics) compared their optimiser with models that experts scaled by hand in
OpenSim; the repository keeps that data (github.com/keenon/AddBiomechanics, ``paper_data/ExpertN``): each subject's
generic model (``generic.osim``), the expert's hand-scaled model (``hand_scaled.osim``), the trials (``.trc``) and the
expert's inverse kinematics of each on the hand-scaled model (``.mot``).  This benchmark calibrates the generic model
with calibrate on each trial (Expert1 with its static, as a lab would; Expert2 has none) and sets it beside the
expert's, both over the frames of the expert's ``.mot`` and the markers both models carry:

- marker RMS (the mean over frames of each frame's RMS over the markers) and mean per-frame largest error, the
  expert's evaluated by OpenSim (a child process: the ``opensim`` package and calibrate's casadi cannot share one)
  at the expert's coordinates, calibrate's by Pinocchio at its own;
- each hip, knee and ankle coordinate's RMS difference from the expert's IK (same model, same coordinates);
- calibrate's wall time for the whole run (scaling, marker placement, every frame's pose), after an untimed
  warm-up that compiles the model's per-frame C code once per machine, as bench_osim does;
- one subject, one model?  Each trial is calibrated with the same static, so the static's mean hip, knee and ankle
  angles should come out the same from every calibration of the subject: their spread (SD, range) over the
  subject's trials says how much of a coordinate's zero is the subject's and how much the trial's (``consistency``).

The data is not in ../shared (GPL-3 with the repository's own terms): give a checkout's root, e.g. one made by
``git clone --depth 1 https://github.com/keenon/AddBiomechanics``, with ``--addbiomechanics DIR``.

    python scripts/bench_expert.py --addbiomechanics DIR [--cases Expert1,Expert2] [--all-trials]
                                   [--config FILE.toml] [--neutral] [--json]

``--config``: calibrate's settings from a config file (calibrate's ``--config`` layout, e.g. ``[priors]
marker_mm = 10``) over the defaults; ``--neutral``: the static is the neutral trial (its angles zero on average,
calibrate's ``--neutral 1``).  Both are recorded in the JSON.
"""

from __future__ import annotations

import argparse
import datetime
import importlib
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_osim import COORDS, marker_scores, read_mot  # noqa: E402  (the scripts folder is not a package)

# Each subject: its static (None: none in the data) and the movement trials benchmarked (each calibrated on its own).
CASES = {
    "Expert1": {"static": "static1", "trials": ("walking1", "squats1", "STS1", "DJ1")},
    "Expert2": {"static": None, "trials": ("run0350cms", "run0500cms")},
}

# The OpenSim child: {"jobs": [{"osim", "mot", "out"}]} -> per job an .npz of the model's markers in ground at each
# row of the .mot (times, names, positions (F, M, 3) m).
_CHILD = r"""
import json, sys
import numpy as np
import opensim as osim
osim.Logger.removeFileSink()
osim.Logger.setLevelString("error")
for job in json.load(open(sys.argv[1]))["jobs"]:
    model = osim.Model(job["osim"])
    state = model.initSystem()
    cs = model.getCoordinateSet()
    for i in range(cs.getSize()):
        cs.get(i).setLocked(state, False)
    sto = osim.Storage(job["mot"])
    if sto.isInDegrees():
        model.getSimbodyEngine().convertDegreesToRadians(sto)
    labels = sto.getColumnLabels()
    cols = [labels.get(i) for i in range(1, labels.getSize())]
    ms = model.getMarkerSet()
    names = [ms.get(i).getName() for i in range(ms.getSize())]
    times, pos = [], []
    for f in range(sto.getSize()):
        row = sto.getStateVector(f)
        data = row.getData()
        for k, c in enumerate(cols):
            if cs.contains(c):
                cs.get(c).setValue(state, data.get(k), False)
        model.realizePosition(state)
        times.append(row.getTime())
        pos.append([ms.get(i).getLocationInGround(state).to_numpy() for i in range(ms.getSize())])
    np.savez(job["out"], times=np.array(times), names=np.array(names), positions=np.array(pos))
"""


def expert_markers(jobs: list[dict], work: Path) -> list[dict]:
    """OpenSim's marker positions of the expert's model at the expert's coordinates, one child for every job."""
    spec = work / "expert_jobs.json"
    spec.write_text(json.dumps({"jobs": jobs}))
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(spec)], capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(f"OpenSim child failed:\n{proc.stderr[-3000:]}")
    out = []
    for job in jobs:
        z = np.load(job["out"])
        out.append({"times": z["times"], "names": [str(n) for n in z["names"]], "positions": z["positions"]})
    return out


def run_calibrate(subject: Path, static: str | None, trial: str, span: tuple[float, float],
                  config: Path | None = None, neutral: bool = False) -> dict:
    """calibrate from the subject's generic.osim on (its static and) the trial cut to `span` (s): the motion's
    markers by Pinocchio, the joint angles and the wall time (the files read inside it).  `config`: settings over
    the defaults (calibrate.io.config); `neutral`: the static is the neutral trial (where there is one)."""
    import pinocchio as pin

    from calibrate.calibration.pipeline import calibrate
    from calibrate.io.config import load_settings
    from calibrate.io.osim_info import with_locked
    from calibrate.io.read import read_trial
    from calibrate.model.model import load_model, write_model
    from calibrate.problem.settings import Settings

    importlib.import_module("calibrate.io.osim")  # imports outside the timing, as OpenSim's are outside its tools
    t0 = time.perf_counter()
    model = load_model(subject / "generic.osim")
    move = read_trial(subject / f"{trial}.trc")
    keep = np.flatnonzero((move.times >= span[0] - 1e-6) & (move.times <= span[1] + 1e-6))
    move = move.frames(int(keep[0]), int(keep[-1]) + 1)
    trials = ([read_trial(subject / f"{static}.trc")] if static else []) + [move]
    cal = calibrate(model, trials, with_locked(model, load_settings(config) if config else Settings()),
                    neutral=0 if neutral and static else None)
    wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        subj = load_model(write_model(cal.model, Path(tmp) / "subject.urdf", cal.params))
    m = cal.motions[-1]
    still = cal.motions[0] if static else None  # the static's mean angles: the same static in every run of a subject
    data = subj.pin.createData()
    ids = [subj.pin.getFrameId(name, pin.FrameType.BODY) for name in subj.marker_names]
    mk = np.zeros((m.n_frames, len(ids), 3))
    for f in range(m.n_frames):
        pin.framesForwardKinematics(subj.pin, data, subj.pin_configuration(m.root_translation[f],
                                                                            m.root_quaternion[f], m.angles[f]))
        mk[f] = [data.oMf[i].translation for i in ids]
    return {"wall_s": wall, "markers": mk, "marker_names": list(subj.marker_names), "trial": cal.trials[-1],
            "times": np.asarray(move.times), "angles": {d: m.angles[:, i] for i, d in enumerate(m.dof_names)},
            "static_angles": {} if still is None else {d: float(np.mean(still.angles[:, i]))
                                                       for i, d in enumerate(still.dof_names)},
            "converged": bool(cal.converged), "moved": [f"{x.marker} {1e3 * x.distance:.0f} mm" for x in cal.moved],
            # the static's cluster labels read as the trial names them (calibrate.calibration.moved.exchanged_clusters)
            "relabelled": [f"{a} as {b}" for x in cal.relabelled for a, b in zip(x.labels, x.read_as, strict=True)],
            # (a position: its distance from the base model's at the subject's scale, which the flag judges)
            "unreliable": [f"{c.group} {c.item} {c.change if c.group == 'axis' else c.beyond_scale:.0f}"
                           for c in cal.changes if c.unreliable]}


def trials_of(subject: Path, case: dict, every: bool) -> tuple[str, ...]:
    """The case's trials, or (`every`) each trial in `subject` with the expert's .mot and a .trc, the static
    excepted, sorted by name."""
    if not every:
        return tuple(case["trials"])
    return tuple(sorted(p.stem for p in subject.glob("*.mot")
                        if (subject / f"{p.stem}.trc").is_file() and p.stem != case["static"]))


def bench(root: Path, name: str, work: Path, log, every: bool = False, config: Path | None = None,
          neutral: bool = False) -> list[dict]:
    """The case's rows; `every`: each trial of the subject that has the expert's .mot (and a .trc), not the case's
    chosen few."""
    case = CASES[name]
    subject = root / "paper_data" / name
    if not (subject / "generic.osim").is_file():
        raise SystemExit(f"{subject}: no generic.osim; give --addbiomechanics the root of an AddBiomechanics checkout")
    case = {**case, "trials": trials_of(subject, case, every)}
    jobs = [{"osim": str(subject / "hand_scaled.osim"), "mot": str(subject / f"{t}.mot"),
             "out": str(work / f"{name}_{t}.npz")} for t in case["trials"]]
    log(f"{name}: the expert's model at the expert's IK (OpenSim, child process) ...")
    expert = expert_markers(jobs, work)
    rows = []
    for trial, ex in zip(case["trials"], expert, strict=True):
        mot_t, mot_cols, mot_q = read_mot(str(subject / f"{trial}.mot"))
        span = (float(mot_t[0]), float(mot_t[-1]))
        log(f"{name} {trial}: warm-up, then calibrate on {'the static + ' if case['static'] else ''}{trial} "
            f"({span[0]:g} to {span[1]:g} s) ...")
        run_calibrate(subject, case["static"], trial, (span[0], min(span[1], span[0] + 0.3)), config, neutral)
        ours = run_calibrate(subject, case["static"], trial, span, config, neutral)
        tr = ours["trial"]
        # The frames of the expert's .mot, in the trial as calibrate read and cut it.
        rows_ours = [int(np.argmin(np.abs(ours["times"] - t))) for t in ex["times"]]
        ok = [k for k, r in enumerate(rows_ours) if abs(ours["times"][r] - ex["times"][k]) < 1e-4]
        rows_ours = [rows_ours[k] for k in ok]
        sub = type(tr)(tr.labels, tr.markers[rows_ours], tr.rate, 0, tr.source)
        use = [m for m in ex["names"] if m in tr.labels and m in ours["marker_names"]]
        ex_scores = marker_scores(ex["positions"][ok], ex["names"], sub, use)
        our_scores = marker_scores(ours["markers"][rows_ours], ours["marker_names"], sub, use)
        angles, at_static = {}, {}
        for side in ("r", "l"):
            for c in COORDS:
                coord = f"{c}_{side}"
                if coord in ours["angles"] and coord in mot_cols:
                    d = np.degrees(ours["angles"][coord][rows_ours] - mot_q[ok, mot_cols.index(coord)])
                    angles[coord] = {"rms_deg": float(np.sqrt(np.mean(d**2))), "offset_deg": float(np.mean(d))}
                if coord in ours["static_angles"]:
                    at_static[coord] = float(np.degrees(ours["static_angles"][coord]))
        rows.append({"subject": name, "trial": trial, "static": case["static"], "frames": len(ok),
                     "markers": len(use), "expert": ex_scores, "calibrate": {**our_scores, "wall_s": ours["wall_s"]},
                     "ratio": our_scores["rms_mm"] / ex_scores["rms_mm"], "angles": angles,
                     "converged": ours["converged"], "moved": ours["moved"], "relabelled": ours["relabelled"],
                     "unreliable": ours["unreliable"],
                     "static_angles_deg": at_static})
    return rows


def consistency(rows: list[dict]) -> dict:
    """Per subject with a static and two or more trials: each hip, knee and ankle coordinate's mean in the static as
    the subject's calibrations read it (each with another trial, the static the same), its SD and range over them;
    and the SD over the trials of its mean offset from the expert's IK (one expert model for all: a calibrated
    subject's own zero would keep it; with --neutral, which zeroes the static, only this figure says anything)."""
    out: dict = {}
    for name in dict.fromkeys(r["subject"] for r in rows):
        mine = [r for r in rows if r["subject"] == name and r.get("static_angles_deg")]
        if len(mine) < 2:
            continue
        coords = [c for c in mine[0]["static_angles_deg"] if all(c in r["static_angles_deg"] for r in mine)]
        out[name] = {"static": mine[0]["static"], "calibrations": len(mine), "coordinates": {
            c: {"sd_deg": float(np.std(v)), "min_deg": float(np.min(v)), "max_deg": float(np.max(v)),
                "offset_sd_deg": float(np.std([r["angles"][c]["offset_deg"] for r in mine]))
                if all(c in r.get("angles", {}) for r in mine) else None}
            for c in coords for v in [np.array([r["static_angles_deg"][c] for r in mine])]}}
    return out


def show(rows: list[dict], same: dict | None = None) -> str:
    out = []
    for r in rows:
        head = f"{r['static']} + {r['trial']}" if r["static"] else r["trial"]
        out.append(f"\n== {r['subject']} {head}: {r['frames']} frames of the expert's IK, {r['markers']} markers "
                   "scored")
        out.append(f"  {'':28s} {'RMS mm':>8s} {'max mm':>8s} {'time s':>8s}")
        out.append(f"  {'expert (hand-scaled + IK)':28s} {r['expert']['rms_mm']:8.2f} {r['expert']['max_mm']:8.2f}")
        out.append(f"  {'calibrate':28s} {r['calibrate']['rms_mm']:8.2f} {r['calibrate']['max_mm']:8.2f} "
                   f"{r['calibrate']['wall_s']:8.2f}   (RMS / expert's: {r['ratio']:.2f})")
        if r["moved"]:
            out.append(f"  calibrate left out the static's positions of: {', '.join(r['moved'])}")
        if r["relabelled"]:
            out.append(f"  calibrate read the static's labels as the trial's: {', '.join(r['relabelled'])}")
        if r["unreliable"]:
            out.append(f"  calibrate's unreliable: {', '.join(r['unreliable'])}")
        worst = sorted(r["angles"].items(), key=lambda kv: -kv[1]["rms_deg"])
        out.append("  hip/knee/ankle vs the expert's IK (deg RMS, mean offset): " + ", ".join(
            f"{k} {v['rms_deg']:.1f} ({v['offset_deg']:+.1f})" for k, v in worst))
    for name, c in (same or {}).items():
        out.append(f"\n== {name}: the static {c['static']} as its {c['calibrations']} calibrations read it (each with "
                   "another trial): mean angle's SD and range over them; the SD over the trials of the mean "
                   "offset from the expert's IK (deg)")
        for k, v in sorted(c["coordinates"].items(), key=lambda kv: -kv[1]["sd_deg"]):
            off = f"   offset SD {v['offset_sd_deg']:5.1f}" if v.get("offset_sd_deg") is not None else ""
            out.append(f"  {k:20s} SD {v['sd_deg']:5.1f}   {v['min_deg']:+6.1f} to {v['max_deg']:+6.1f}{off}")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--addbiomechanics", type=Path, required=True, metavar="DIR",
                    help="root of an AddBiomechanics checkout (its paper_data/ExpertN folders)")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated among {', '.join(CASES)}")
    ap.add_argument("--all-trials", action="store_true",
                    help="every trial with the expert's .mot (Expert1: 25, Expert2: 4), not each case's chosen few")
    ap.add_argument("--config", type=Path, default=None, metavar="FILE",
                    help="calibrate's settings from this config file (TOML, calibrate's --config layout)")
    ap.add_argument("--neutral", action="store_true",
                    help="the static is the neutral trial: its joint angles zero on average (calibrate's --neutral)")
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    args = ap.parse_args(argv)
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    bad = [c for c in cases if c not in CASES]
    if bad:
        print(f"bench_expert: unknown case {bad[0]!r}; give some of {', '.join(CASES)}", file=sys.stderr)
        return 2
    if not (args.addbiomechanics / "paper_data").is_dir():
        print(f"bench_expert: {args.addbiomechanics}: no paper_data folder; give the root of an AddBiomechanics "
              "checkout (git clone --depth 1 https://github.com/keenon/AddBiomechanics)", file=sys.stderr)
        return 2
    if args.config is not None:  # read before anything runs: a bad file is refused in one line
        from calibrate.errors import CalibrateError
        from calibrate.io.config import load_settings

        try:
            load_settings(args.config)
        except CalibrateError as e:
            print(f"bench_expert: {e}", file=sys.stderr)
            return 2

    def log(msg: str) -> None:
        print(msg, file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_expert_") as tmp:
        for c in cases:
            rows += bench(args.addbiomechanics, c, Path(tmp), log, args.all_trials, args.config, args.neutral)
    result = {"rows": rows, "consistency": consistency(rows), "config": str(args.config) if args.config else None,
              "neutral": args.neutral,
              "machine": f"{platform.processor() or platform.machine()}, {platform.python_version()}",
              "date": datetime.datetime.now().isoformat(timespec="minutes"), "wall_s": time.perf_counter() - t0}
    if args.json:
        print(json.dumps(result))
    else:
        print(show(rows, result["consistency"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
