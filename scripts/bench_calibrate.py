"""Benchmark the global calibration (seed 003) on simulated full-body squats.

1. accuracy: `calibrate` on `simulate_squats` trials of models/human.urdf (default 1000 frames),
   noise-free, with 1 mm marker noise, and with 1 mm noise from a base model scaled 0.85 and
   1.15 (basin of convergence); errors from `calibrate.calibration.evaluate.compare_to_truth`; then a treadmill
   gait trial (`simulate_gait`, same frames, 1 mm noise; no targets), with the axes of still
   coordinates held (the default) and left free (auto_hold=False);
2. speed: time per stage and peak memory of each calibration (every timed run in a fresh
   subprocess of this script, after one untimed warm-up that compiles the model's C code),
   the whole command line (`python -m calibrate.cli TRIAL MODEL ...`) on 1000 frames, and a
   10 000-frame calibration (linearity);
3. the same problem (seed, start and Problem exactly as `calibrate` builds them) solved by our
   Levenberg-Marquardt, by scipy.optimize.least_squares (trf + lsmr, exact sparse Jacobian)
   and by IPOPT through casadi.nlpsol (exact Hessian, assembled from per-frame CasADi Hessians):
   time, iterations and final cost, each evaluated by Problem.cost.

Targets are printed PASS/FAIL; the exit status is 0 whatever they say.

    python scripts/bench_calibrate.py [--frames 1000] [--compare-frames 1000] [--seed 0] [--quick] [--json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "human.urdf"
# (name, marker noise mm, base-model scale)
SCENARIOS = (("noise-free", 0.0, 1.0), ("1 mm noise", 1.0, 1.0), ("1 mm, base x0.85", 1.0, 0.85),
             ("1 mm, base x1.15", 1.0, 1.15))
NOISE_FREE_STATED_MM = 0.001  # the noise SD the solver is told for noise-free data (--noise-mm 0.001)
MAIN = "1 mm noise"  # the scenario behind the top-level figures and the 1000-frame speed targets
FIT_STAGES = ("seed", "start", "build", "solve")  # "seed + global solve" (covariance, load, write excluded)
# targets (issue): metres, degrees, seconds, MB
NOISE_FREE_RMS = 1e-6
NOISE_FREE_BALL_MM = 0.1
NOISE_FREE_AXIS_DEG = 0.01
RMS_OVER_FLOOR = 1.05
BALL_MEDIAN_MM = 2.0
BALL_MAX_MM = 5.0
HINGE_AXIS_DEG = 1.0
HINGE_CENTRE_MM = 2.0
ANGLE_RMS_DEG = 0.5
FIT_S_1K = 2.0
CLI_S_1K = 5.0
PEAK_MB = 1024.0
FIT_S_10K = 20.0
LINEAR = 1.2  # time per frame (per iteration) at 10k frames over that at 1k frames


# ====================================================================== child processes
def run_child(cmd: list[str], cap: float, env: dict[str, str] | None = None) -> dict:
    """Run `cmd` (in `env`, default this process's), killing it after `cap` seconds: wall time, exit status,
    peak memory (wait4), output."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, cwd=ROOT, env=env)
        timer = threading.Timer(cap, proc.kill)
        timer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            timer.cancel()
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return {"rc": proc.returncode, "seconds": wall, "peak_mb": usage.ru_maxrss / 1024,
                "timed_out": proc.returncode < 0 and wall >= cap, "stdout": out.read().decode(errors="replace"),
                "stderr": err.read().decode(errors="replace")}


def worker(kind: str, spec: dict, cap: float) -> dict:
    """Run `kind` (see WORKERS) in a fresh process of this script; its result, or what went wrong."""
    with tempfile.TemporaryDirectory() as tmp:
        result = Path(tmp) / "result.json"
        progress = Path(tmp) / "progress.txt"
        spec = {**spec, "progress": str(progress)}
        child = run_child([sys.executable, str(Path(__file__).resolve()), "--_worker", kind,
                           "--_spec", json.dumps(spec), "--_out", str(result)], cap)
        out = json.loads(result.read_text()) if result.exists() else {}
        out["process_s"] = child["seconds"]
        out["process_peak_mb"] = child["peak_mb"]
        out["progress"] = parse_progress(progress.read_text()) if progress.exists() else {}
        if not result.exists():
            out["error"] = (f"stopped at the {cap:.0f} s cap" if child["timed_out"] else
                            f"exit {child['rc']}: " + (child["stderr"].strip().splitlines() or ["no output"])[-1])
        return out


def parse_progress(text: str) -> dict:
    """Stage start times and solver iterations from a worker's progress log ('seconds<TAB>message')."""
    stages: dict[str, float] = {}
    its: list[tuple[float, int]] = []
    full_its: list[tuple[float, int]] = []
    last = 0.0
    for line in text.splitlines():
        t, _, msg = line.partition("\t")
        last = float(t)
        stage = msg.split(":")[0]
        stages.setdefault(stage, last)
        if msg.startswith("solve: iteration"):
            its.append((last, int(msg.split()[2])))
        elif msg.startswith("solve: all frames, iteration"):  # the solve on every frame (after the coarse one)
            full_its.append((last, int(msg.split()[4])))
    its = full_its or its  # per-iteration time of the solve on every frame, where there is one
    per_it = math.nan
    if len(its) >= 2 and its[-1][1] > its[0][1]:
        per_it = (its[-1][0] - its[0][0]) / (its[-1][1] - its[0][1])
    return {"stage_start_s": stages, "last_s": last, "iterations_seen": its[-1][1] if its else 0,
            "s_per_iteration": per_it}


# ====================================================================== workers (run in the child)
def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _logger(path: str):
    """A calibrate progress callback writing 'seconds since start<TAB>message' lines."""
    f = open(path, "w", buffering=1)  # noqa: SIM115 - open for the worker's lifetime
    t0 = time.perf_counter()
    return lambda msg: f.write(f"{time.perf_counter() - t0:.4f}\t{msg}\n")


def base_model(scale: float, tmp: str):
    """models/human.urdf, or the same with every segment scaled by `scale`."""
    from calibrate.model.model import Parameters, load_model, write_model

    model = load_model(MODEL)
    if scale == 1.0:
        return model
    b = model.parameters()
    path = write_model(model, Path(tmp) / f"base_{scale:g}.urdf",
                       Parameters(scale * np.ones(len(model.segments)), b.centre, b.axis, b.marker))
    return load_model(path)


def work_warmup(spec: dict) -> dict:
    """A short calibration: compiles and caches the model's C code, warms the file cache."""
    from calibrate.calibration.pipeline import calibrate
    from calibrate.model.model import load_model
    from calibrate.problem.settings import Settings
    from calibrate.simulation.simulate import simulate_squats

    model = load_model(MODEL)
    sim = simulate_squats(model, 100, seed=spec["seed"])
    t0 = time.perf_counter()
    cal = calibrate(model, sim.trial, Settings(max_iterations=3))
    return {"seconds": time.perf_counter() - t0, "compiled": bool(cal.compiled)}


def work_calibrate(spec: dict) -> dict:
    """One timed `calibrate` of a simulated trial, then (untimed) its errors against the truth."""
    from calibrate.calibration.evaluate import compare_to_truth
    from calibrate.calibration.pipeline import calibrate
    from calibrate.model.model import load_model
    from calibrate.problem.settings import Settings
    from calibrate.simulation.simulate import simulate_gait, simulate_squats

    with tempfile.TemporaryDirectory() as tmp:
        model = base_model(spec["scale"], tmp)
        simulate = simulate_gait if spec.get("motion") == "gait" else simulate_squats
        sim = simulate(load_model(MODEL), spec["frames"], noise_mm=spec["noise_mm"], seed=spec["seed"])
        before = _peak_mb()
        say = _logger(spec["progress"])
        t0 = time.perf_counter()
        # The solver is told the data's noise, as a user does with --noise-mm: noise-free data are
        # weighted as 1 um noise (at the default 1 mm the chi-square stopping rule stops at ~10 um).
        settings = Settings(noise=max(spec["noise_mm"], NOISE_FREE_STATED_MM) / 1000,
                            auto_hold=spec.get("auto_hold", True))
        cal = calibrate(model, sim.trial, settings, progress=say)
        wall = time.perf_counter() - t0
        peak = _peak_mb()
        s = cal.summary
        out = {"frames": spec["frames"], "noise_mm": spec["noise_mm"], "scale": spec["scale"], "seed": spec["seed"],
               "calibrate_s": wall, "times": dict(cal.times), "peak_mb": peak, "peak_mb_before": before,
               "iterations": s.iterations, "accepted": s.accepted, "converged": bool(s.converged),
               "termination": s.termination, "initial_cost": s.initial_cost, "final_cost": s.final_cost,
               "compiled": bool(cal.compiled), "marker_rms_m": cal.marker_rms, "held_axes": list(cal.held_axes),
               "unidentified": [c.name for c in cal.unidentified],
               "axis_std_deg": {c.item: float(np.nanmax(c.std)) for c in cal.changes if c.group == "axis"}}
        if spec.get("truth", True):
            c = compare_to_truth(cal, sim)
            out.update({"centre_err_m": c.centre_error, "axis_err_deg": c.axis_error_deg, "kinds": c.kinds,
                        "floor_rms_m": c.floor_rms, "angle_rms_deg": c.angle_rms_deg,
                        "angle_rms_offset_free_deg": c.angle_rms_offset_free_deg,
                        "angle_rms_per_dof_deg": c.angle_rms_per_dof_deg,
                        "floor_angle_rms_deg": c.floor_angle_rms_deg})
        return out


def work_compare(spec: dict) -> dict:
    """One problem, built as `calibrate` builds it, solved by ours, scipy and IPOPT (see compare_solvers)."""
    from threadpoolctl import threadpool_limits

    from calibrate.calibration.start import start_poses
    from calibrate.model.kinematics import build_kinematics
    from calibrate.model.model import load_model
    from calibrate.problem.problem import Problem
    from calibrate.problem.settings import Priors, Settings
    from calibrate.problem.state import State
    from calibrate.seed.seeding import seed_parameters
    from calibrate.simulation.simulate import simulate_squats
    from calibrate.solve.ik import marker_columns

    model = load_model(MODEL)
    sim = simulate_squats(model, spec["frames"], noise_mm=1.0, seed=spec["seed"])
    t0 = time.perf_counter()
    # Without the left/right symmetry prior: the IPOPT objective writes Problem.prior out symbolically
    # without that block (the comparison is of solvers on one cost, not of the defaults).
    settings = Settings(priors=Priors(symmetry_scale=0.0, symmetry_centre=0.0))
    kin = build_kinematics(model)
    obs = marker_columns(model, sim.trial)
    seed = seed_parameters(model, sim.trial)
    # calibrate() runs everything with one BLAS thread; so does every solver here.
    with threadpool_limits(limits=1, user_api="blas"):
        state0 = start_poses(kin, obs, seed.params)
        # In the URDF's angles (every ball's reference the identity): the form the baselines solve in.
        state0 = State(*kin.absolute(state0.Z, state0.Q, state0.B), state0.p)
        problem = Problem(model, obs, settings, kin)
        setup = time.perf_counter() - t0
        out = compare_solvers(problem, state0, spec, settings.solver)
    out.update({"frames": spec["frames"], "setup_s": setup, "n_free": problem.n_free,
                "variables": problem.F * model.nz + problem.n_free})
    return out


WORKERS = {"warmup": work_warmup, "calibrate": work_calibrate, "compare": work_compare}


# ====================================================================== the three solvers
def compare_solvers(problem, state0, spec: dict, options) -> dict:
    """Ours, scipy and IPOPT from `state0` (`options`: the solver options, SolverOptions, ours and scipy's
    tolerances); every final cost is problem.cost of the final State."""
    from calibrate.solve.lm import levenberg_marquardt

    out: dict = {"initial_cost": problem.cost(state0)}
    t0 = time.perf_counter()
    state, summary = levenberg_marquardt(problem, state0, options)
    out["ours"] = {"seconds": time.perf_counter() - t0, "iterations": summary.iterations,
                   "accepted": summary.accepted, "cost": problem.cost(state), "summary_cost": summary.final_cost,
                   "status": summary.termination, "converged": bool(summary.converged)}
    out["scipy"] = solve_scipy(problem, state0, spec["cap"], options)
    out["ipopt"] = solve_ipopt(problem, state0, spec["cap"], spec["hessian"])
    return out


def baseline_state(problem, state0, x: np.ndarray, T0: np.ndarray):
    """State at x = [vec(dZ), x_p]: Z = Z0 + dZ (q_ref fixed), p = p0 + T0 x_p (axes not renormalised)."""
    from calibrate.problem.state import State

    F, nz = problem.F, problem.model.nz
    return State(state0.Z + x[:F * nz].reshape(F, nz), state0.Q, state0.p + T0 @ x[F * nz:])


class _Cap(Exception):
    """The time cap of a baseline solver was reached."""


def solve_scipy(problem, state0, cap: float, options) -> dict:
    """scipy.optimize.least_squares (trf, lsmr, x_scale='jac') on the residual vector with our exact sparse
    Jacobian; stopped at `cap` seconds (the best point evaluated so far is kept)."""
    from scipy.optimize import least_squares

    st = options
    T0 = problem.tangent_map(state0.p)
    n = problem.F * problem.model.nz + problem.n_free
    J0 = problem.full_jacobian(state0, T0)[1]
    sparsity = J0.copy()
    sparsity.data[:] = 1.0
    best = {"cost": math.inf, "x": np.zeros(n), "nfev": 0, "njev": 0}
    t0 = time.perf_counter()

    def fun(x: np.ndarray) -> np.ndarray:
        if time.perf_counter() - t0 > cap:
            raise _Cap
        e = problem.residual_vector(baseline_state(problem, state0, x, T0))
        best["nfev"] += 1
        c = 0.5 * float(e @ e)
        if c < best["cost"]:
            best["cost"], best["x"] = c, x.copy()
        return e

    def jac(x: np.ndarray):
        if time.perf_counter() - t0 > cap:
            raise _Cap
        best["njev"] += 1
        return problem.full_jacobian(baseline_state(problem, state0, x, T0), T0)[1]

    status, capped = "", False
    try:
        res = least_squares(fun, np.zeros(n), jac=jac, jac_sparsity=sparsity, method="trf", tr_solver="lsmr",
                            x_scale="jac", ftol=st.ftol, xtol=st.xtol, gtol=st.gtol, max_nfev=1000)
        x, status = res.x, f"status {res.status}: {res.message}"
    except _Cap:
        x, capped, status = best["x"], True, f"stopped at the {cap:.0f} s cap (best point so far)"
    seconds = time.perf_counter() - t0
    return {"seconds": seconds, "nfev": best["nfev"], "njev": best["njev"], "capped": capped, "status": status,
            "cost": problem.cost(baseline_state(problem, state0, x, T0)), "jac_nnz": int(J0.nnz),
            "jac_shape": list(J0.shape)}


def ipopt_objective(problem, state0, hessian: bool):
    """Symbolic cost of `problem` (linear loss) over x = [vec(dZ), x_p], and an exact Hessian function.

    Data and joint limits are one SX function per frame (markers from Kinematics.h with q_ref fixed
    to state0.Q; unseen markers weighted 0), mapped over the frames with x_p shared; the prior is
    Problem.prior written symbolically.  The Hessian (IPOPT's hess_lag) is assembled from the per-frame
    SX Hessians (z-z and z-p blocks per frame, p-p summed over frames) plus the prior's: CasADi's own
    Hessian of the whole mapped graph takes minutes to build even for 50 frames."""
    import casadi as ca

    from calibrate.problem.problem import LIMIT_WEIGHT

    st, m, kin = problem.settings, problem.model, problem.kin
    if st.loss != "linear":
        raise ValueError("the IPOPT baseline reproduces the linear loss only")
    F, nz, n, nm = problem.F, m.nz, problem.n_free, len(m.markers)
    p0 = state0.p
    T0 = problem.tangent_map(p0)
    z, xp = ca.SX.sym("z", nz), ca.SX.sym("xp", n)
    q, r, w = ca.SX.sym("q", 4), ca.SX.sym("r", 3 * nm), ca.SX.sym("w", 3 * nm)
    p = ca.DM(p0) + ca.mtimes(ca.sparsify(ca.DM(T0)), xp)
    markers, _ = kin.h(z, q, p)
    th = z[6:]
    so3 = [d for b in kin.balls for d in b.dofs]  # no limit term on balls (on SO(3) in Problem)
    lo = np.where(np.isfinite(problem.lower), problem.lower, -1e20)
    hi = np.where(np.isfinite(problem.upper), problem.upper, 1e20)
    lo[so3], hi[so3] = -1e20, 1e20
    outside = th - ca.fmin(ca.fmax(th, lo), hi)
    frame = 0.5 * ca.sumsqr(w * (ca.vec(markers) - r) / st.noise) + 0.5 * (LIMIT_WEIGHT / st.noise) ** 2 * ca.sumsqr(
        outside)
    # prior, as Problem.prior
    L, pri, base = problem.layout, st.priors, problem.base.vector()
    res = []
    for group, count, seg_of, sigma in (("marker", nm, problem.marker_segment, pri.marker),
                                        ("centre", len(m.joints), problem.centre_segment, pri.centre)):
        if group in st.free:
            for i in range(count):
                sl = L.block(group, i).full
                res.append(p[int(seg_of[i])] * (p[sl] - base[sl]) / sigma)
    for d in problem.axis_dofs:
        sl = L.axis(d)
        res.append((p[sl] - base[sl] / np.linalg.norm(base[sl])) / pri.axis)
    if "scale" in st.free:
        ns = len(m.segments)
        res.append((p[:ns] - base[:ns]) / pri.scale)
    prior = 0.5 * ca.sumsqr(ca.vertcat(*res)) if res else ca.SX(0)

    x = ca.MX.sym("x", F * nz + n)
    Z = ca.DM(state0.Z.T) + ca.reshape(x[:F * nz], nz, F)
    X = x[F * nz:]
    data = (ca.DM(state0.Q.T), ca.DM(problem.target.T), ca.DM(np.repeat(problem.seen, 3, axis=1).T.astype(float)))
    per_frame = ca.Function("frame_cost", [z, xp, q, r, w], [frame])
    prior_f = ca.Function("prior", [xp], [prior, ca.densify(ca.hessian(prior, xp)[0])])
    f = per_frame.map("frames_cost", "thread", F, [1], [0])(Z, X, *data) + prior_f(X)[0]
    if not hessian:
        return x, f, None, T0
    H = ca.triu(ca.hessian(frame, ca.vertcat(z, xp))[0])
    Hzz, Hzp = H[:nz, :nz], H[:nz, nz:]
    per_frame_h = ca.Function("frame_hess", [z, xp, q, r, w],
                              [ca.vertcat(*Hzz.nonzeros()), ca.vertcat(*Hzp.nonzeros()), ca.densify(H[nz:, nz:])])
    hzz, hzp, hpp = per_frame_h.map("frames_hess", "thread", F, [1], [2])(Z, X, *data)
    hpp = hpp + prior_f(X)[1]
    # Scatter into the upper triangle of the full Hessian, nonzeros in column-major order.
    rz, cz = (np.array(a) for a in Hzz.sparsity().get_triplet())
    rp, cp = (np.array(a) for a in Hzp.sparsity().get_triplet())
    fr = np.arange(F)[:, None]
    iu, ju = np.triu_indices(n)
    rows = np.concatenate([(fr * nz + rz).ravel(), (fr * nz + rp).ravel(), F * nz + iu])
    cols = np.concatenate([(fr * nz + cz).ravel(), (F * nz + cp + 0 * fr).ravel(), F * nz + ju])
    src = np.concatenate([np.arange(F * rz.size), F * rz.size + np.arange(F * rp.size),
                          F * (rz.size + rp.size) + ju * n + iu])
    order = np.lexsort((rows, cols))
    N = F * nz + n
    sp = ca.Sparsity.triplet(N, N, rows[order].tolist(), cols[order].tolist())
    values = ca.vertcat(ca.vec(hzz), ca.vec(hzp), ca.vec(hpp))[src[order].tolist()]
    lam_f = ca.MX.sym("lam_f")
    hess = ca.Function("nlp_hess_l", [x, ca.MX.sym("p", 0), lam_f, ca.MX.sym("lam_g", 0)],
                       [lam_f * ca.MX(sp, values)], ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
    return x, f, hess, T0


def ipopt_checks(problem, state0) -> dict:
    """The symbolic objective against problem.cost at x = 0, and the assembled Hessian against CasADi's
    own on the first 3 frames."""
    import casadi as ca

    from calibrate.problem.problem import Problem
    from calibrate.problem.state import State

    x, f, _, _ = ipopt_objective(problem, state0, hessian=False)
    c_sym = float(ca.Function("f", [x], [f])(np.zeros(x.numel())))
    c_ref = problem.cost(state0)
    k = min(3, problem.F)
    obs = np.where(problem.seen[:k, :, None], problem.target[:k].reshape(k, -1, 3), np.nan)
    small = Problem(problem.model, obs, problem.settings, problem.kin)
    s3 = State(state0.Z[:k], state0.Q[:k], state0.p)
    xs, fs, hs, _ = ipopt_objective(small, s3, hessian=True)
    x1 = 1e-3 * np.random.default_rng(0).normal(size=xs.numel())
    H_ad = np.array(ca.densify(ca.Function("h", [xs], [ca.triu(ca.hessian(fs, xs)[0])])(x1)))
    H_us = np.array(ca.densify(hs(x1, [], 1.0, [])))
    return {"cost_symbolic": c_sym, "cost_problem": c_ref, "cost_rel_diff": abs(c_sym - c_ref) / abs(c_ref),
            "hessian_rel_diff_3_frames": float(np.abs(H_ad - H_us).max() / np.abs(H_ad).max())}


def solve_ipopt(problem, state0, cap: float, hessian: str) -> dict:
    """IPOPT (casadi.nlpsol) on the symbolic cost from x = 0; stopped at `cap` seconds (wall and CPU)."""
    import casadi as ca

    out = ipopt_checks(problem, state0)
    t0 = time.perf_counter()
    exact = hessian == "exact"
    x, f, hess, T0 = ipopt_objective(problem, state0, hessian=exact)
    opts = {"print_time": False, "ipopt.print_level": 0, "ipopt.sb": "yes", "ipopt.max_iter": 3000,
            "ipopt.max_wall_time": cap, "ipopt.max_cpu_time": 2 * cap}
    opts.update({"hess_lag": hess} if exact else {"ipopt.hessian_approximation": "limited-memory"})
    solver = ca.nlpsol("ipopt_baseline", "ipopt", {"x": x, "f": f}, opts)
    build = time.perf_counter() - t0
    t1 = time.perf_counter()
    sol = solver(x0=np.zeros(x.numel()))
    solve = time.perf_counter() - t1
    stats = solver.stats()
    xs = np.asarray(sol["x"]).ravel()
    out.update({"seconds": build + solve, "build_s": build, "solve_s": solve, "iterations": int(stats["iter_count"]),
                "status": str(stats["return_status"]), "capped": "Time" in str(stats["return_status"]),
                "ipopt_cost": float(sol["f"]), "cost": problem.cost(baseline_state(problem, state0, xs, T0)),
                "hessian": "exact (assembled per-frame SX Hessians)" if exact else "limited-memory (L-BFGS)"})
    return out


# ====================================================================== parent: the benchmark
def scenario_metrics(r: dict) -> dict:
    """The figures of one calibration run (mm, degrees, seconds)."""
    if "centre_err_m" not in r:
        return {}
    kinds = r["kinds"]
    ball = [1e3 * v for k, v in r["centre_err_m"].items() if kinds[k] != "hinge"]
    hinge = [1e3 * v for k, v in r["centre_err_m"].items() if kinds[k] == "hinge"]
    allc = [1e3 * v for v in r["centre_err_m"].values()]
    axes = list(r["axis_err_deg"].values())
    fit = sum(r["times"].get(k, 0.0) for k in FIT_STAGES)
    return {"marker_rms_mm": 1e3 * r["marker_rms_m"], "floor_rms_mm": 1e3 * r["floor_rms_m"],
            # (noise-free: the floor is ~0 and the ratio meaningless)
            "rms_over_floor": r["marker_rms_m"] / r["floor_rms_m"] if r["floor_rms_m"] > 1e-6 else math.nan,
            "ball_centre_mm_median": float(np.median(ball)), "ball_centre_mm_max": max(ball),
            "hinge_centre_mm_max": max(hinge), "all_centre_mm_median": float(np.median(allc)),
            "all_centre_mm_max": max(allc), "axis_deg_max": max(axes),
            "worst_ball": max((v, k) for k, v in r["centre_err_m"].items() if kinds[k] != "hinge")[1],
            "worst_hinge_centre": max((v, k) for k, v in r["centre_err_m"].items() if kinds[k] == "hinge")[1],
            "worst_axis": max((v, k) for k, v in r["axis_err_deg"].items())[1],
            "angle_rms_deg": r["angle_rms_deg"], "angle_rms_offset_free_deg": r["angle_rms_offset_free_deg"],
            "floor_angle_rms_deg": r.get("floor_angle_rms_deg", math.nan),
            "worst_axis_std_deg": r.get("axis_std_deg", {}).get(max((v, k) for k, v in r["axis_err_deg"].items())[1],
                                                                math.nan),
            "fit_s": fit}


def accuracy_checks(name: str, m: dict) -> list[tuple[str, bool]]:
    """The issue's accuracy targets for one scenario."""
    if not m:
        return [(f"{name}: calibration did not finish", False)]
    if name == "noise-free":
        return [(f"{name}: marker RMS {m['marker_rms_mm'] * 1e3:.3g} um <= {NOISE_FREE_RMS * 1e6:g} um",
                 m["marker_rms_mm"] <= NOISE_FREE_RMS * 1e3),
                (f"{name}: ball-joint centres, worst {m['ball_centre_mm_max']:.3f} mm ({m['worst_ball']}) "
                 f"<= {NOISE_FREE_BALL_MM} mm", m["ball_centre_mm_max"] <= NOISE_FREE_BALL_MM),
                (f"{name}: hinge axes, worst {m['axis_deg_max']:.4f} deg ({m['worst_axis']}) "
                 f"<= {NOISE_FREE_AXIS_DEG} deg", m["axis_deg_max"] <= NOISE_FREE_AXIS_DEG)]
    return [(f"{name}: marker RMS {m['marker_rms_mm']:.4f} mm = {m['rms_over_floor']:.4f} x noise floor "
             f"{m['floor_rms_mm']:.4f} mm, <= {RMS_OVER_FLOOR}", m["rms_over_floor"] <= RMS_OVER_FLOOR),
            (f"{name}: ball-joint centres, median {m['ball_centre_mm_median']:.2f} mm <= {BALL_MEDIAN_MM} mm",
             m["ball_centre_mm_median"] <= BALL_MEDIAN_MM),
            (f"{name}: ball-joint centres, worst {m['ball_centre_mm_max']:.2f} mm ({m['worst_ball']}) <= "
             f"{BALL_MAX_MM} mm", m["ball_centre_mm_max"] <= BALL_MAX_MM),
            (f"{name}: hinge axes, worst {m['axis_deg_max']:.2f} deg ({m['worst_axis']}; its posterior SD "
             f"{m['worst_axis_std_deg']:.2f} deg) <= {HINGE_AXIS_DEG} deg", m["axis_deg_max"] <= HINGE_AXIS_DEG),
            (f"{name}: hinge centres from the true axis, worst {m['hinge_centre_mm_max']:.2f} mm "
             f"({m['worst_hinge_centre']}) <= {HINGE_CENTRE_MM} mm", m["hinge_centre_mm_max"] <= HINGE_CENTRE_MM),
            (f"{name}: joint angles RMS {m['angle_rms_deg']:.2f} deg <= {ANGLE_RMS_DEG} deg "
             f"(offset-free: {m['angle_rms_offset_free_deg']:.2f} deg; the true model refitted frame by frame: "
             f"{m['floor_angle_rms_deg']:.2f} deg)", m["angle_rms_deg"] <= ANGLE_RMS_DEG)]


def cli_run(frames: int, seed: int, cap: float) -> dict:
    """`calibrate simulate` (untimed), then the timed `calibrate TRIAL MODEL -o ... --overwrite -q`."""
    with tempfile.TemporaryDirectory() as tmp:
        cli = [sys.executable, "-m", "calibrate.cli"]
        sim = run_child(cli + ["simulate", "--out", tmp, "--frames", str(frames), "--seed", str(seed)], cap)
        if sim["rc"] != 0:
            return {"error": "calibrate simulate failed: " + sim["stderr"].strip()[-300:]}
        r = run_child(cli + [str(Path(tmp) / "trial.c3d"), str(MODEL), "-o", str(Path(tmp) / "subject.urdf"),
                             "--overwrite", "-q"], cap)
        out = {"frames": frames, "seconds": r["seconds"], "peak_mb": r["peak_mb"], "rc": r["rc"],
               "command": "python -m calibrate.cli TRIAL models/human.urdf -o SUBJECT.urdf --overwrite -q"}
        if r["timed_out"]:
            out["error"] = f"stopped at the {cap:.0f} s cap"
        elif r["rc"] not in (0, 1):
            out["error"] = f"exit {r['rc']}: " + r["stderr"].strip()[-300:]
        return out


def stopped(r: dict) -> str:
    """What a worker that did not finish got to (from its progress log)."""
    pr = r.get("progress", {})
    if not pr.get("stage_start_s"):
        return r["error"]
    stages = pr["stage_start_s"]
    last = max(stages, key=stages.get)
    return (f"{r['error']}: reached '{last}' at {pr.get('last_s', 0):.0f} s, "
            f"{pr.get('iterations_seen', 0)} solver iterations")


def fmt(x, spec: str = ".2f") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def clean_json(x):
    """NaN/inf -> None, recursively, so the output is strict JSON."""
    if isinstance(x, dict):
        return {str(k): clean_json(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [clean_json(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, np.generic):
        return clean_json(x.item())
    return x


def machine() -> dict:
    import casadi
    import scipy

    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                   if ln.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
            "scipy": scipy.__version__, "casadi": casadi.__version__}


def collect(a: argparse.Namespace, log) -> dict:
    """Run every measurement (workers in fresh processes); the results and the targets as one dict."""
    frames = a.frames or (300 if a.quick else 1000)
    cframes = a.compare_frames or (200 if a.quick else 1000)
    cap = a.cap or (20.0 if a.quick else 300.0)
    t_start = time.perf_counter()
    res: dict = {"quick": a.quick, "seed": a.seed, "frames": frames, "compare_frames": cframes, "cap_s": cap}

    from calibrate.model.model import load_model
    from calibrate.problem.problem import Problem
    from calibrate.problem.settings import Settings

    model = load_model(MODEL)
    n_free = Problem(model, np.zeros((2, len(model.markers), 3)), Settings(compile=False)).n_free
    res.update({"markers": len(model.markers), "dof": model.nz, "joint_dofs": model.n_dofs, "n_params": n_free,
                "n_params_full": len(model.parameters().vector()), "segments": len(model.segments),
                "joints": len(model.joints)})
    log("warm-up calibration (compiles the model's C code on a new machine)")
    res["warmup"] = worker("warmup", {"seed": a.seed}, 900)

    # 1. accuracy
    checks: list[tuple[str, bool]] = []
    res["scenarios"] = {}
    for name, noise, scale in SCENARIOS:
        log(f"accuracy: {name}, {frames} frames")
        r = worker("calibrate", {"frames": frames, "noise_mm": noise, "scale": scale, "seed": a.seed}, 3600)
        r["metrics"] = scenario_metrics(r)
        res["scenarios"][name] = r
        checks += accuracy_checks(name, r["metrics"])

    # 1b. treadmill gait: no targets; the held axes against leaving them free
    res["gait"] = {}
    for label, auto in (("axes of still joints held", True), ("all axes free", False)):
        log(f"accuracy: gait, {label}, {frames} frames")
        r = worker("calibrate", {"frames": frames, "noise_mm": 1.0, "scale": 1.0, "seed": a.seed, "motion": "gait",
                                 "auto_hold": auto}, 3600)
        r["metrics"] = scenario_metrics(r)
        res["gait"][label] = r

    # 2. speed: the 1 mm-noise accuracy run is the timed run at `frames`
    main_run = res["scenarios"][MAIN]
    mm = main_run["metrics"]
    speed: dict = {"frames": frames, "fit_s": mm.get("fit_s"), "times": main_run.get("times", {}),
                   "peak_mb": main_run.get("peak_mb"), "s_per_iteration": main_run["progress"].get("s_per_iteration")}
    cli_frames = frames if a.quick else 1000
    log(f"speed: command line, {cli_frames} frames")
    speed["cli"] = cli = cli_run(cli_frames, a.seed, 900)
    if not a.quick:
        log(f"speed: {a.big_frames} frames (cap {a.big_cap:.0f} s)")
        big = worker("calibrate", {"frames": a.big_frames, "noise_mm": 1.0, "scale": 1.0, "seed": a.seed,
                                   "truth": False}, a.big_cap)
        big["frames"] = a.big_frames
        big["fit_s"] = sum(big["times"].get(k, 0.0) for k in FIT_STAGES) if "times" in big else None
        speed["big"] = big
        checks.append((f"{frames} frames: seed + start + build + solve {fmt(mm.get('fit_s'))} s <= {FIT_S_1K} s",
                       mm.get("fit_s") is not None and mm["fit_s"] <= FIT_S_1K))
        checks.append((f"{cli_frames} frames: whole CLI run {fmt(cli.get('seconds'))} s <= {CLI_S_1K} s",
                       "error" not in cli and cli["seconds"] <= CLI_S_1K))
        checks.append((f"{frames} frames: peak memory {fmt(main_run.get('peak_mb'), '.0f')} MB <= {PEAK_MB:.0f} MB",
                       main_run.get("peak_mb") is not None and main_run["peak_mb"] <= PEAK_MB))
        if "error" in big:
            checks.append((f"{a.big_frames} frames: seed..solve > {a.big_cap:.0f} s ({big['error']}) <= {FIT_S_10K} s",
                           False))
        else:
            checks.append((f"{a.big_frames} frames: seed + start + build + solve {fmt(big['fit_s'])} s "
                           f"<= {FIT_S_10K} s", big["fit_s"] <= FIT_S_10K))
            if mm.get("fit_s"):
                speed["time_per_frame_ratio"] = (big["fit_s"] / a.big_frames) / (mm["fit_s"] / frames)
        per_it_big = big["progress"].get("s_per_iteration")
        ratio = math.nan
        if per_it_big and speed.get("s_per_iteration"):
            ratio = (per_it_big / a.big_frames) / (speed["s_per_iteration"] / frames)
        speed["iteration_time_per_frame_ratio"] = ratio
        checks.append((f"linear in frames: time per solver iteration per frame, {a.big_frames} vs {frames} frames, "
                       f"{fmt(ratio)}x <= {LINEAR}", math.isfinite(ratio) and ratio <= LINEAR))
    res["speed"] = speed

    # 3. the same problem, three solvers
    log(f"comparison: {cframes} frames, ours / scipy / IPOPT (caps {cap:.0f} s)")
    cmp = worker("compare", {"frames": cframes, "seed": a.seed, "cap": cap, "hessian": a.ipopt_hessian},
                 3 * cap + 1800)
    res["comparison"] = cmp
    if "error" not in cmp:
        ip, scp, ours = cmp["ipopt"], cmp["scipy"], cmp["ours"]
        res.update({"ipopt_s": ip["seconds"], "scipy_s": scp["seconds"], "ours_compare_s": ours["seconds"],
                    "ipopt_capped": ip["capped"], "scipy_capped": scp["capped"], "ours_compare_cost": ours["cost"],
                    "ipopt_cost": ip["cost"], "scipy_cost": scp["cost"],
                    "ipopt_ratio": ip["seconds"] / ours["seconds"], "scipy_ratio": scp["seconds"] / ours["seconds"]})
        checks.append((f"IPOPT objective equals problem.cost at the start (rel. diff {ip['cost_rel_diff']:.1e} "
                       "<= 1e-9)", ip["cost_rel_diff"] <= 1e-9))
    else:
        checks.append((f"solver comparison ran ({cmp['error']})", False))

    res.update({"iterations": main_run.get("iterations"), "solve_s": main_run.get("times", {}).get("solve"),
                "seed_to_solve_s": mm.get("fit_s"), "total_s": main_run.get("calibrate_s"),
                "peak_mb": main_run.get("peak_mb"), "cli_s": cli.get("seconds"),
                "marker_rms_mm": mm.get("marker_rms_mm"), "floor_rms_mm": mm.get("floor_rms_mm"),
                "joint_centre_err_mm_median": mm.get("ball_centre_mm_median"),
                "joint_centre_err_mm_max": mm.get("ball_centre_mm_max"),
                "hinge_centre_err_mm_max": mm.get("hinge_centre_mm_max"), "axis_err_deg_max": mm.get("axis_deg_max"),
                "angle_rms_deg": mm.get("angle_rms_deg"), "angle_floor_deg": mm.get("floor_angle_rms_deg"),
                "converged": main_run.get("converged"),
                "notes": "top-level figures: the 1 mm-noise run at `frames`; joint_centre_err_mm_*: ball and "
                         "universal joints (hinges: hinge_centre_err_mm_max, distance from the true axis line); "
                         "angle_floor_deg: joint angles of the true model refitted frame by frame (the noise floor); "
                         "total_s: calibrate() wall time; seed_to_solve_s: seed + start + build + solve; "
                         "peak_mb: the calibration process's peak RSS; ipopt_s / scipy_s: on compare_frames frames, "
                         "capped at cap_s (see *_capped)"})
    for key in ("ipopt_s", "scipy_s"):
        res.setdefault(key, None)
    res["checks"] = [{"target": t, "pass": bool(p)} for t, p in checks]
    res["machine"] = machine()
    res["date"] = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    res["wall_s"] = time.perf_counter() - t_start
    return res


def report(res: dict) -> None:
    """Print the tables and targets of a `collect` result (also one read back from --json output)."""
    say = print
    sc, speed, cmp = res["scenarios"], res["speed"], res["comparison"]
    frames, names = res["frames"], [n for n, _, _ in SCENARIOS]
    w = res.get("warmup", {})
    say(f"Global calibration benchmark: {MODEL.name} ({res['segments']} segments, {res['joints']} joints, "
        f"{res['dof']} coordinates per frame, {res['markers']} markers, {res['n_params']} free parameters); "
        f"simulate_squats seed {res['seed']}{'; --quick' if res['quick'] else ''}")
    say(f"Warm-up (untimed): a 100-frame calibration in its own process first, {fmt(w.get('seconds'))} s, compiled "
        f"C: {w.get('compiled')} (a machine's first run compiles and caches the model's C code)"
        + (f"; ERROR {w['error']}" if "error" in w else ""))

    say()
    say(f"1. Accuracy: {frames} frames, calibrate() from models/human.urdf (or it scaled), errors vs truth "
        "(compare_to_truth; medians over frames)")
    say(f"{'':28s}" + "".join(f"{n:>18s}" for n in names))
    rows = [("marker RMS (mm)", "marker_rms_mm", ".4f"), ("noise floor RMS (mm)", "floor_rms_mm", ".4f"),
            ("RMS / floor", "rms_over_floor", ".4f"), ("ball centres median (mm)", "ball_centre_mm_median", ".3f"),
            ("ball centres max (mm)", "ball_centre_mm_max", ".3f"),
            ("hinge centres max (mm)", "hinge_centre_mm_max", ".3f"), ("hinge axes max (deg)", "axis_deg_max", ".3f"),
            ("joint angles RMS (deg)", "angle_rms_deg", ".3f"),
            ("  offset-free (deg)", "angle_rms_offset_free_deg", ".3f"),
            ("  true model refitted (deg)", "floor_angle_rms_deg", ".3f"),
            ("worst axis posterior SD (deg)", "worst_axis_std_deg", ".3f")]
    for label, key, spec in rows:
        say(f"{label:28s}" + "".join(f"{fmt(sc[n]['metrics'].get(key), spec):>18s}" for n in names))
    say(f"{'iterations (accepted)':28s}" + "".join(
        f"{(str(sc[n]['iterations']) + ' (' + str(sc[n]['accepted']) + ')') if 'iterations' in sc[n] else '-':>18s}"
        for n in names))
    say(f"{'converged':28s}" + "".join(f"{str(sc[n].get('converged', '-')):>18s}" for n in names))
    order = list(FIT_STAGES) + ["covariance"]
    stages = sorted({k for n in names for k in sc[n].get("times", {})},
                    key=lambda k: order.index(k) if k in order else len(order))
    for k in stages:
        say(f"{'time ' + k + ' (s)':28s}" + "".join(f"{fmt(sc[n].get('times', {}).get(k)):>18s}" for n in names))
    say(f"{'seed..solve (s)':28s}" + "".join(f"{fmt(sc[n]['metrics'].get('fit_s')):>18s}" for n in names))
    say(f"{'calibrate() total (s)':28s}" + "".join(f"{fmt(sc[n].get('calibrate_s')):>18s}" for n in names))
    for n in names:
        if "error" in sc[n]:
            say(f"  {n}: ERROR {stopped(sc[n])}")
        elif not sc[n].get("converged"):
            say(f"  {n}: not converged: {sc[n].get('termination')}")
    gait = res.get("gait", {})
    if gait:
        say()
        say(f"1b. Treadmill gait (simulate_gait), {frames} frames, 1 mm noise (no targets: forearms, wrists, neck "
            "and subtalar joints move a few degrees)")
        gn = list(gait)
        say(f"{'':30s}" + "".join(f"{n:>28s}" for n in gn))
        for label, key, spec in (("marker RMS / floor", "rms_over_floor", ".4f"),
                                 ("ball centres median (mm)", "ball_centre_mm_median", ".2f"),
                                 ("ball centres max (mm)", "ball_centre_mm_max", ".2f"),
                                 ("angles offset-free (deg)", "angle_rms_offset_free_deg", ".2f"),
                                 ("seed..solve (s)", "fit_s", ".2f")):
            say(f"{label:30s}" + "".join(f"{fmt(gait[n]['metrics'].get(key), spec):>28s}" for n in gn))
        axes = sorted({k for n in gn for k in gait[n].get("axis_err_deg", {})})
        for k in axes:
            say(f"{'axis ' + k + ' (deg)':30s}" + "".join(f"{fmt(gait[n].get('axis_err_deg', {}).get(k)):>28s}"
                                                           for n in gn))
        for n in gn:
            say(f"  {n}: held {', '.join(gait[n].get('held_axes', [])) or 'none'}"
                + (f"; ERROR {stopped(gait[n])}" if "error" in gait[n] else ""))
    say("Largest joint-angle errors (RMS over frames, deg, raw):")
    for n in names:
        per = sc[n].get("angle_rms_per_dof_deg")
        if per:
            worst = sorted(per.items(), key=lambda kv: -kv[1])[:5]
            say(f"  {n + ':':18s} " + ", ".join(f"{k} {v:.2f}" for k, v in worst))
    ref = next((sc[n] for n in names if "kinds" in sc[n]), None)
    if ref is not None:
        say()
        say("Per joint: centre error mm (hinge: distance from the true axis line) / hinge axis error deg")
        say(f"{'joint':14s} {'kind':9s}    " + "".join(f"{n:>18s}" for n in names))
        for j, kind in ref["kinds"].items():
            cells = []
            for n in names:
                r = sc[n]
                ax = r.get("axis_err_deg", {}).get(j)
                held = set(r.get("unidentified", []))
                star = {k: "*" if f"{k}[{j}]" in held else "" for k in ("centre", "axis")}
                cells.append("-" if "centre_err_m" not in r else f"{1e3 * r['centre_err_m'][j]:.2f}{star['centre']}"
                             + (f" / {ax:.2f}{star['axis']}" if ax is not None else ""))
            say(f"{j:14s} {kind:9s}    " + "".join(f"{c:>18s}" for c in cells))
        say("* calibrate() reports it as not identified by the trial, in at least one direction (held there by "
            "its prior; every hinge centre is, along its axis)")

    say()
    m = res["machine"]
    say(f"2. Speed: calibrate() of the '{MAIN}' trial, each run in a fresh process; {m['cpu']}, {m['cores']} cores")
    say(f"{'frames':>8s} {'seed':>7s} {'start':>7s} {'build':>7s} {'solve':>8s} {'seed..solve':>12s} "
        f"{'covariance':>11s} {'iterations':>11s} {'s/iteration':>12s} {'peak MB':>8s}")
    runs = [(frames, sc[MAIN])] + ([(speed["big"]["frames"], speed["big"])] if "big" in speed else [])
    for F, r in runs:
        t = r.get("times", {})
        fit = sum(t.get(k, 0.0) for k in FIT_STAGES) if t else None
        its = r.get("iterations", r.get("progress", {}).get("iterations_seen"))
        say(f"{F!s:>8s} {fmt(t.get('seed')):>7s} {fmt(t.get('start')):>7s} {fmt(t.get('build')):>7s} "
            f"{fmt(t.get('solve')):>8s} {fmt(fit):>12s} {fmt(t.get('covariance')):>11s} {its!s:>11s} "
            f"{fmt(r.get('progress', {}).get('s_per_iteration'), '.3f'):>12s} "
            f"{fmt(r.get('peak_mb', r.get('process_peak_mb')), '.0f'):>8s}"
            + (f"   {stopped(r)}" if "error" in r else ""))
    if "time_per_frame_ratio" in speed:
        say(f"time per frame (seed..solve), big run vs {frames} frames: {fmt(speed['time_per_frame_ratio'])}x")
    if "iteration_time_per_frame_ratio" in speed:
        say(f"time per solver iteration per frame, big run vs {frames} frames: "
            f"{fmt(speed['iteration_time_per_frame_ratio'])}x")
    cli = speed["cli"]
    say(f"whole command line, {cli.get('frames')} frames: {fmt(cli.get('seconds'))} s wall, peak "
        f"{fmt(cli.get('peak_mb'), '.0f')} MB, exit {cli.get('rc')}  ({cli.get('command')})"
        + (f"  ERROR {cli['error']}" if "error" in cli else ""))
    if res["quick"]:
        say("(--quick: the speed targets, for 1000 and 10 000 frames, are not judged)")

    say()
    say(f"3. The same problem, three solvers: {res['compare_frames']} frames, 1 mm noise, seed/start/Problem as in "
        f"calibrate(); baselines capped at {res['cap_s']:.0f} s; one BLAS thread for all")
    if "error" in cmp:
        say(f"  ERROR {cmp['error']}")
    else:
        ip, scp, ours = cmp["ipopt"], cmp["scipy"], cmp["ours"]
        say(f"  {cmp['variables']} unknowns ({cmp['frames']} frames x {res['dof']} coordinates + {cmp['n_free']} "
            f"parameters); setup (seed, start, Problem) {cmp['setup_s']:.2f} s; initial cost {cmp['initial_cost']:.6e}")
        say(f"  IPOPT objective check at x = 0: symbolic {ip['cost_symbolic']:.10e} vs problem.cost "
            f"{ip['cost_problem']:.10e}, relative difference {ip['cost_rel_diff']:.1e} "
            f"{'PASS' if ip['cost_rel_diff'] <= 1e-9 else 'FAIL'} (<= 1e-9); assembled Hessian vs CasADi's own on "
            f"3 frames: relative difference {ip['hessian_rel_diff_3_frames']:.1e}")
        say(f"  {'solver':44s} {'time (s)':>9s} {'x ours':>8s} {'iterations':>11s} {'final cost':>14s} "
            f"{'vs ours':>10s}  status")
        c0 = ours["cost"]
        lines = [("ours: levenberg_marquardt (Schur on p)", ours["seconds"], False, f"{ours['iterations']}",
                  ours["cost"], ours["status"]),
                 ("scipy least_squares trf/lsmr, exact jac", scp["seconds"], scp["capped"], f"{scp['njev']} jac",
                  scp["cost"], scp["status"] + f"; {scp['nfev']} fun evals"),
                 (f"IPOPT, {ip['hessian'].split(' (')[0]} Hessian (MUMPS)", ip["seconds"], ip["capped"],
                  f"{ip['iterations']}", ip["cost"],
                  f"{ip['status']}; build {ip['build_s']:.1f} s; IPOPT's own f {ip['ipopt_cost']:.6e}")]
        for label, s, capped, its, c, status in lines:
            more = ">" if capped else ""  # stopped at the cap: the time is a lower bound
            say(f"  {label:44s} {more + format(s, '.2f'):>9s} {more + format(s / ours['seconds'], '.2f'):>7s}x "
                f"{its:>11s} {c:14.6e} {c / c0 - 1:+10.2e}  {status}")
        say(f"  IPOPT Hessian: {ip['hessian']}.  Final costs are problem.cost of each final State.  Ours holds "
            "the gauge directions (segment frames' free turns, hinge centres' slides) with constraints; the "
            "baselines minimise the same cost without them.  scipy uses jac_sparsity only for finite "
            "differences, so with the exact Jacobian it is inert.")

    say()
    say("Targets")
    for c in res["checks"]:
        say(f"  {'PASS' if c['pass'] else 'FAIL'}  {c['target']}")
    say(f"\n{m['cpu']} ({m['cores']} cores), Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}, "
        f"CasADi {m['casadi']}; {res['date']}; benchmark wall time {res['wall_s']:.0f} s")


def output_args(ap: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """The options every benchmark script shares: --json, --from-json, and the hidden ones of its child
    processes (--_worker KIND --_spec JSON --_out FILE)."""
    ap.add_argument("--json", action="store_true", help="print one JSON object (nothing else on stdout)")
    ap.add_argument("--from-json", type=Path, default=None, help="print the tables of a saved --json result")
    ap.add_argument("--_worker", help=argparse.SUPPRESS)
    ap.add_argument("--_spec", help=argparse.SUPPRESS)
    ap.add_argument("--_out", help=argparse.SUPPRESS)
    return ap


def worker_or_saved(a: argparse.Namespace, workers: dict, report) -> bool:
    """Run the child's worker (writing its result) or print a saved result's tables: True if done so."""
    if a._worker:
        Path(a._out).write_text(json.dumps(clean_json(workers[a._worker](json.loads(a._spec)))))
        return True
    if a.from_json:
        report(json.loads(a.from_json.read_text()))
        return True
    return False


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=None, help="frames of the accuracy runs (default 1000; quick 300)")
    ap.add_argument("--compare-frames", type=int, default=None,
                    help="frames of the solver comparison (default 1000; quick 200)")
    ap.add_argument("--big-frames", type=int, default=10000, help="frames of the linearity run (default 10000)")
    ap.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    ap.add_argument("--quick", action="store_true", help="CI smoke: 300 frames, no 10k run, compare on 200 frames")
    ap.add_argument("--cap", type=float, default=None, help="time cap (s) of each baseline solver (default 300; "
                                                             "quick 20)")
    ap.add_argument("--big-cap", type=float, default=900.0, help="time cap (s) of the 10k-frame run (default 900)")
    ap.add_argument("--ipopt-hessian", choices=("exact", "limited-memory"), default="exact")
    a = output_args(ap).parse_args()
    if worker_or_saved(a, WORKERS, report):
        return
    t0 = time.perf_counter()
    res = collect(a, lambda msg: print(f"[{time.perf_counter() - t0:6.0f} s] {msg}", file=sys.stderr, flush=True))
    if a.json:
        print(json.dumps(clean_json(res)))
    else:
        report(res)


if __name__ == "__main__":
    main()
