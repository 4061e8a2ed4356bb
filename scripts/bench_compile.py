"""What a model's compiled per-frame code costs, and what another marker set on the same model costs.

On an empty compile cache (a temporary $CALIBRATE_CACHE): the calibration problem of each base model built
once (its C compiled), then the same model with other marker sets — three markers added (a lab's own
labels), a third of its markers left out, both — each built again (compiled again, or not), and the
evaluation of a trial's residuals and Jacobians (Problem._run: "full" with ∂/∂z and ∂/∂p, "pose" with ∂/∂z,
"resid" alone) over 600 simulated frames, and one frame's markers and Jacobian at a time as frame-wise fits
evaluate them (Problem.frame_evaluator, µs a call).  Run it on two checkouts (PYTHONPATH) to compare.

    python scripts/bench_compile.py [--frames 600] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from calibrate.model.model import Model, add_markers, load_model
from calibrate.problem.problem import Problem
from calibrate.problem.settings import Settings
from calibrate.problem.state import State
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import marker_columns

ROOT = Path(__file__).resolve().parent.parent
MODELS = {"human": ROOT / "models" / "human.urdf",
          "rajagopal": ROOT.parent / "shared" / "data" / "real" / "rajagopal_walk" / "Rajagopal2016.osim"}


def remove_markers(model: Model, names: list[str]) -> Model:
    """`model` without the markers `names` (their links and fixed joints taken out of its URDF text)."""
    robot = ET.fromstring(model.text)
    for el in list(robot):
        child = el.find("child")
        if (el.tag == "link" and el.get("name") in names) or (el.tag == "joint" and child is not None
                                                               and child.get("link") in names):
            robot.remove(el)
    return Model(model.path, text=ET.tostring(robot, encoding="unicode"))


def _variants(model):
    """The base model and three other marker sets on it: (name, model)."""
    segs = [mk.segment for mk in model.markers]
    extra = {f"LAB{i}": (segs[(7 * i) % len(segs)], np.array([0.01 * i, 0.03, -0.02])) for i in range(3)}
    dropped = [mk.name for mk in model.markers[::3]]
    return [("base", model), ("3 added", add_markers(model, extra)), ("a third out", remove_markers(model, dropped)),
            ("both", add_markers(remove_markers(model, dropped), extra))]


def _build(model) -> tuple[float, bool]:
    t = time.perf_counter()
    problem = Problem(model, np.zeros((2, len(model.markers), 3)), Settings())
    return time.perf_counter() - t, problem.compiled


def _evaluation_ms(model, frames: int) -> dict[str, float]:
    """Median ms of one evaluation of each kind over `frames` simulated squat frames."""
    sim = simulate_squats(model, frames=frames, noise_mm=1.0, seed=4)
    obs = marker_columns(model, sim.trial)
    m = sim.motion
    state = State(np.column_stack([m.root_translation, np.zeros((frames, 3)), m.angles]), m.root_quaternion.copy(),
                  sim.truth.vector())
    problem = Problem(model, obs, Settings())
    out = {}
    for kind in ("full", "pose", "resid"):
        o = problem._run(kind, state)
        times = []
        for _ in range(30):
            t = time.perf_counter()
            o = problem._run(kind, state, o)
            times.append(time.perf_counter() - t)
        out[kind] = 1e3 * float(np.median(times))
    # One frame's markers and dense Jacobian at a time, as frame-wise fits call it (thousands of calls a run).
    ev = problem.frame_evaluator(state.p)
    refs = problem.kin.refs(state.Q, state.B)
    rounds = []
    for _ in range(5):
        t = time.perf_counter()
        for f in range(frames):
            ev(state.Z[f], refs[f])
        rounds.append((time.perf_counter() - t) / frames)
    out["one_frame_us"] = 1e6 * float(np.median(rounds))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as cache:
        os.environ["CALIBRATE_CACHE"] = cache
        for name, path in MODELS.items():
            if not path.exists():
                print(f"{name}: {path} not found, skipped")
                continue
            model = load_model(path)
            for variant, mv in _variants(model):
                seconds, compiled = _build(mv)
                libraries = len(list(Path(cache).glob("frame_*.so")))
                rows.append({"model": name, "markers": variant, "n_markers": len(mv.markers), "build_s": seconds,
                             "compiled": compiled, "libraries": libraries})
                print(f"{name:10s} {variant:12s} {len(mv.markers):3d} markers: problem built in {seconds:6.2f} s "
                      f"(compiled {compiled}; {libraries} libraries in the cache)")
            ev = _evaluation_ms(model, args.frames)
            rows.append({"model": name, "evaluation_ms": ev, "frames": args.frames})
            kinds = ", ".join(f"{k} {v:.2f} ms" for k, v in ev.items() if k != "one_frame_us")
            print(f"{name:10s} {args.frames} frames: {kinds}; one frame {ev['one_frame_us']:.1f} µs")
    if args.json:
        args.json.write_text(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.processor()
                                         or platform.machine(), "cpus": os.cpu_count(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
