"""Benchmark the symbolic kinematics against Pinocchio on models/human.urdf.

Per frame: marker positions, and positions + Jacobian w.r.t. the coordinates z, by
  (a) calibrate's CasADi functions (Python call, and the preallocated FrameEvaluator),
  (b) Pinocchio (forwardKinematics + updateFramePlacements; computeJointJacobians +
      getFrameJacobian per marker), the numeric reference;
and for a whole trial the mapped CasADi evaluation vs a Python loop over Pinocchio.
Also the frame-wise IK of a 1000-frame squat trial (CasADi's virtual machine, and the compiled code).

    python scripts/bench_kinematics.py [--frames 1000] [--json]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from calibrate.model.kinematics import build_kinematics
from calibrate.model.model import load_model
from calibrate.problem.problem import compiled_kinematics
from calibrate.simulation.simulate import simulate_squats
from calibrate.solve.ik import inverse_kinematics

MODEL = Path(__file__).resolve().parent.parent / "models" / "human.urdf"


def per_call_us(fn, min_time: float = 0.5) -> float:
    """Median over 5 rounds of the mean time per call (µs)."""
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        if time.perf_counter() - t0 > 0.05:
            break
        n *= 2
    rounds = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        rounds.append((time.perf_counter() - t0) / n * 1e6)
    return float(np.median(rounds))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    a = ap.parse_args()

    t0 = time.perf_counter()
    model = load_model(MODEL)
    t_load = time.perf_counter() - t0
    t0 = time.perf_counter()
    kin = build_kinematics(model)
    t_build = time.perf_counter() - t0
    p = model.parameters()
    pv = p.vector()
    rng = np.random.default_rng(0)
    quat = rng.normal(size=4)
    quat /= np.linalg.norm(quat)
    th = rng.uniform(-1, 1, model.n_dofs)
    z = np.concatenate([[0.1, 0.2, 0.9], np.zeros(3), th])
    q = model.pin_configuration(z[:3], quat, th)
    pm, data = model.pin, model.pin.createData()
    fids = [pm.getFrameId(m.name, pin.FrameType.BODY) for m in model.markers]
    ev = kin.frame_evaluator(pv)

    def pin_fk():
        pin.forwardKinematics(pm, data, q)
        pin.updateFramePlacements(pm, data)
        return [data.oMf[i].translation for i in fids]

    def pin_fk_jac():
        pin.computeJointJacobians(pm, data, q)
        pin.updateFramePlacements(pm, data)
        return [pin.getFrameJacobian(pm, data, i, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED) for i in fids]

    res = {
        "model": {"markers": len(model.markers), "dof": 6 + model.n_dofs, "n_params": int(pv.size)},
        "load_s": t_load, "build_s": t_build,
        "fk_us": {
            "casadi_call": per_call_us(lambda: np.asarray(kin.h(z, quat, pv)[0])),
            "pinocchio": per_call_us(pin_fk),
        },
        "fk_jac_z_us": {
            "casadi_call": per_call_us(lambda: [np.asarray(x) for x in kin.h_jz(z, quat, pv)]),
            "casadi_frame_evaluator": per_call_us(lambda: ev(z, quat)),
            "pinocchio": per_call_us(pin_fk_jac),
        },
        "fk_jac_zp_us": {"casadi_call": per_call_us(lambda: [np.asarray(x) for x in kin.jac(z, quat, pv)])},
    }
    sim = simulate_squats(model, frames=a.frames, noise_mm=1.0, seed=0)
    Z, Q = sim.motion.z(), sim.motion.root_quaternion
    t0 = time.perf_counter()
    kin.batch(Z, Q, p)
    t_batch = time.perf_counter() - t0
    qs = [model.pin_configuration(Z[f, :3], Q[f], Z[f, 6:]) for f in range(a.frames)]
    t0 = time.perf_counter()
    for qq in qs:
        pin.forwardKinematics(pm, data, qq)
        pin.updateFramePlacements(pm, data)
        [data.oMf[i].translation.copy() for i in fids]
    t_pin_loop = time.perf_counter() - t0
    res["trial_fk_s"] = {"frames": a.frames, "casadi_map": t_batch, "pinocchio_loop": t_pin_loop}
    t0 = time.perf_counter()
    fit_true = inverse_kinematics(kin, sim.trial, sim.truth)
    t_ik_true = time.perf_counter() - t0
    t0 = time.perf_counter()
    fit_base = inverse_kinematics(kin, sim.trial, p)
    t_ik_base = time.perf_counter() - t0
    # ... and on the model's compiled C code (compiled_kinematics: what labelling and the calibration's start run;
    # compiled once per structure and machine, outside the timing)
    kc = compiled_kinematics(kin)
    t0 = time.perf_counter()
    fit_cc = inverse_kinematics(kc, sim.trial, sim.truth)
    t_ik_cc = time.perf_counter() - t0
    res["ik"] = {"frames": a.frames, "true_model_s": t_ik_true, "true_model_rms_mm": fit_true.rms * 1e3,
                 "true_model_iterations": float(fit_true.iterations.mean()),
                 "base_model_s": t_ik_base, "base_model_rms_mm": fit_base.rms * 1e3,
                 "base_model_iterations": float(fit_base.iterations.mean()),
                 # (None without a C compiler: nothing compiled)
                 "true_model_compiled_s": t_ik_cc if kc.compiled is not None else None,
                 "true_model_compiled_same_poses": bool(np.array_equal(fit_cc.motion.angles, fit_true.motion.angles))
                 if kc.compiled is not None else None}
    res["machine"] = {"python": platform.python_version(), "cpu": platform.processor() or platform.machine(),
                      "pinocchio": pin.__version__}
    if a.json:
        print(json.dumps(res))
        return
    m = res["model"]
    print(f"models/human.urdf: {m['markers']} markers, {m['dof']} DoF, {m['n_params']} parameters; "
          f"load {t_load:.3f} s, build CasADi functions {t_build:.3f} s")
    print(f"{'per frame':36s} {'CasADi call':>12s} {'FrameEvaluator':>15s} {'Pinocchio':>10s} {'ratio':>7s}")
    fk, fj = res["fk_us"], res["fk_jac_z_us"]
    print(f"{'markers':36s} {fk['casadi_call']:9.1f} µs {'':>15s} {fk['pinocchio']:7.1f} µs "
          f"{fk['casadi_call'] / fk['pinocchio']:6.2f}x")
    print(f"{'markers + d/dz':36s} {fj['casadi_call']:9.1f} µs {fj['casadi_frame_evaluator']:12.1f} µs "
          f"{fj['pinocchio']:7.1f} µs {fj['casadi_frame_evaluator'] / fj['pinocchio']:6.2f}x")
    zp = res["fk_jac_zp_us"]["casadi_call"]
    print(f"{'markers + d/dz + d/dp (exact)':36s} {zp:9.1f} µs   (no Pinocchio equivalent)")
    tf = res["trial_fk_s"]
    print(f"trial of {a.frames} frames, markers: CasADi map {tf['casadi_map'] * 1e3:.1f} ms, Pinocchio loop "
          f"{tf['pinocchio_loop'] * 1e3:.1f} ms ({tf['pinocchio_loop'] / tf['casadi_map']:.1f}x)")
    ik = res["ik"]
    print(f"frame-wise IK, {a.frames} frames: true model {ik['true_model_s']:.2f} s "
          f"({ik['true_model_rms_mm']:.2f} mm, {ik['true_model_iterations']:.1f} it/frame); base model "
          f"{ik['base_model_s']:.2f} s ({ik['base_model_rms_mm']:.2f} mm, {ik['base_model_iterations']:.1f} it/frame)")
    if ik["true_model_compiled_s"] is not None:
        print(f"  the true model on its compiled C code {ik['true_model_compiled_s']:.2f} s "
              f"({ik['true_model_s'] / ik['true_model_compiled_s']:.1f}x sooner; "
              f"{'the same' if ik['true_model_compiled_same_poses'] else 'other'} poses to the bit)")


if __name__ == "__main__":
    main()
