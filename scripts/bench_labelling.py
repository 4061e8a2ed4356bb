"""Labelling unlabelled trajectories of skin markers (issue 20): label_tracks on trials whose labels are
removed and shuffled, against their true labels.

Cases: the real Plug-in Gait walk and static trial (../shared/data/real/pig_walk; its 39 markers the base
model carries) and simulated squats and gait with soft-tissue artefact (`sta_mm` 3 and 10, 600 frames,
0.5 mm noise).  Per case: tracks labelled right, wrongly, left unlabelled; which route labelled them
(seed 002's rigid groups, or the base model fitted: calibrate.track.fitting); wall time.  The same cases
through calibrate.track.fitting.fit_labels alone.  In-process, one case after the other.

    python scripts/bench_labelling.py [--json] [--quick]
"""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np
from bench_calibrate import machine

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT.parent / "shared" / "data" / "real" / "pig_walk"


def cases(quick: bool) -> list[tuple[str, object]]:
    """(name, a function giving the labelled trial) for every case present."""
    from calibrate.io.read import read_trial
    from calibrate.model.model import load_model
    from calibrate.simulation.simulate import simulate_gait, simulate_squats

    model = load_model(ROOT / "models" / "human.urdf")
    out: list[tuple[str, object]] = []
    if (REAL / "walk.c3d").exists():
        out.append(("pig_walk walk (real)", lambda: read_trial(REAL / "walk.c3d")))
        if not quick:
            out.append(("pig_walk static (real)", lambda: read_trial(REAL / "static.c3d")))
    for motion, simulate in (("gait", simulate_gait), ("squats", simulate_squats)):
        for sta in ((3.0,) if quick else (3.0, 10.0)):
            for seed in ((0,) if quick else (0, 2)):
                out.append((f"{motion}, STA {sta:g} mm, seed {seed}",
                            lambda s=simulate, a=sta, e=seed: s(model, 600, noise_mm=0.5, sta_mm=a, seed=e).trial))
    return out


def one(model, kin, trial, how: str, seed: int = 0) -> dict:
    """Label `trial`'s model markers with their labels removed and shuffled: the counts and the time."""
    from calibrate.errors import CalibrateError
    from calibrate.io.trial import Trial
    from calibrate.track.fitting import fit_labels
    from calibrate.track.labels import label_tracks

    keep = [i for i, name in enumerate(trial.labels) if name in model.marker_names]
    perm = np.random.default_rng(seed).permutation(keep)
    truth = {f"track{k:02d}": trial.labels[i] for k, i in enumerate(perm)}
    tracks = Trial(list(truth), trial.markers[:, perm], trial.rate, trial.first_frame, trial.source)
    t0 = time.perf_counter()
    try:
        if how == "label_tracks":
            lab = label_tracks(model, tracks)
            labels, route = lab.labels, ("groups" if lab.segments else "fitted")
        else:
            labels, route = fit_labels(model, kin, tracks).labels, "fitted"
    except CalibrateError as e:
        return {"error": str(e), "seconds": time.perf_counter() - t0, "tracks": len(truth)}
    seconds = time.perf_counter() - t0
    wrong = {truth[t]: m for t, m in labels.items() if m != truth[t]}
    return {"tracks": len(truth), "right": sum(labels.get(t) == m for t, m in truth.items()), "wrong": wrong,
            "unlabelled": sum(t not in labels for t in truth), "route": route, "seconds": seconds}


def report(res: dict) -> None:
    print(f"# labelling, {res['date']}, {res['machine']['cpu']}, {res['machine']['cores']} cores")
    for how in ("label_tracks", "fit_labels"):
        print(f"\n{how}:")
        print(f"  {'case':32s} {'right':>9s} {'wrong':>6s} {'none':>5s} {'route':>7s} {'s':>6s}  wrong labels")
        for name, r in res[how].items():
            if "error" in r:
                print(f"  {name:32s} refused ({r['seconds']:.1f} s): {r['error'][:80]}")
                continue
            w = ", ".join(f"{a}->{b}" for a, b in r["wrong"].items())
            print(f"  {name:32s} {r['right']:>3d} of {r['tracks']:<3d} {len(r['wrong']):>6d} {r['unlabelled']:>5d} "
                  f"{r['route']:>7s} {r['seconds']:6.1f}  {w}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    ap.add_argument("--quick", action="store_true", help="the real walk and two simulated cases")
    a = ap.parse_args()
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model

    model = load_model(ROOT / "models" / "human.urdf")
    kin = build_kinematics(model)
    res = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"), "machine": machine(),
           "label_tracks": {}, "fit_labels": {}}
    for name, make in cases(a.quick):
        trial = make()
        for how in ("label_tracks", "fit_labels"):
            res[how][name] = one(model, kin, trial, how)
            print(f"{how} {name}: {res[how][name].get('right', 'refused')} right, "
                  f"{res[how][name]['seconds']:.1f} s", file=sys.stderr, flush=True)
    if a.json:
        print(json.dumps(res))
    else:
        report(res)


if __name__ == "__main__":
    main()
