"""The full benchmark (`make bench`): printed as tables, saved as JSON; never asserted.

Sections (`--only a,b,...` to pick; `--quick` for a short smoke run):
  steps     microseconds per smooth step: SVC and SVA with the constraint ignored, and every method
            in its constrained loop before the first impact (cart-pendulum, beta = 3.2, t < 0.729)
  sim5      ms per 5-second cart-pendulum simulation (beta = 3.2, three impacts) at h = 1e-2, 3.2e-2:
            compiled loop (`traj.wall_time`) and whole `simulate()` call; the paper's Table II beside
  impact    cost of one impact, instrumented: one grid step containing an impact minus one smooth
            step, both run by the compiled loop (`integrate`, N = 1) from the real grid states of a
            trajectory, called from a compiled driver (no Python overhead in the difference)
  build     kernel build per method, cold (fresh cache dir, new process) and warm (second process):
            import, time to the first finished simulation, symbolic seconds, symbolic modules imported
  sweep     `vcirun sweep configs/fig4.yaml` (408 runs + 51 references) cold and warm, subprocess,
            separate output file, --force, every core
  yardstick the same work by a plain numpy/scipy CVA (bench/plain_numpy.py, same trajectory) and by
            solve_ivp (DOP853 / Radau, compiled or numpy right-hand side) at matched L2 error
  scaling   cost against T, the number of impacts, 1/h, mh_order (generalized MCVA, cold builds) and
            the degrees of freedom (n-link pendulum, n = 1, 2, 4, 8: symbolic, numba build, us/step),
            with fitted exponents (CVA, MCVAC, MCVAA)
  dof       only the degrees-of-freedom part of `scaling`
  coldbuild cold builds: the first simulation of a scene with a FRESH kernel cache, one
            fresh process at a time, per stage (sympy, emission, C compiler, numba frontend / typing /
            lowering, LLVM, cache write) and per compiled function (bench/coldbuild.py), cart-pendulum
            and n-link pendulum n = 2, 4, 8 x CVA, MCVAC, MCVAA on the default kernel backend, the
            cart-pendulum also on the numba backend (VCIRUN_KERNEL_BACKEND=numba; set
            VCIRUN_BENCH_NUMBA_ALL=1 for every case: the 8-link MCVAA takes ~10 minutes); the
            issue's target table with wall and CPU seconds and the load average beside each
  contacts  cost of an added inactive constraint: microseconds per step of the
            cart-pendulum declared in YAML with its floor only, and with a second constraint that is
            never touched (a ceiling 100 m up), every method in its constrained loop before the first
            impact (h = 1e-5, t < 0.729); the difference against the smooth SVC step (target < 10 %)
  bodies    contacts by the hundred (bench/bodies_scaling.py): cold build, us per smooth step and the
            first-hit outcome against NNLS of cradles of N = 3, 10, 30, 100 balls, and link chains of
            3, 5, 10 links declared by bodies (one fresh process per case)
  cacheverify the kernel cache's checks on a warm start (bench/cache_verify.py): fresh processes of an
            MCVAC simulation with the digest checks and with them replaced by unchecked loads, medians of
            the process wall and of the time spent hashing
  reference the exact reference (bench/reference_bench.py): its cost per built-in scene on the Taylor
            and the DOP853 path beside one run of each method; its issue's targets in this one process
            (random box states with a wrong event sequence, the cart-pendulum reference against one MCVAA
            simulate(), its error against an independent long-double solve, fig4's references and runs)
  tol       simulate(tol=...) and tr.error_estimate() against the exact reference (bench/tolerance.py):
            random states of four scenes, tol = 1e-3 .. 1e-9, the issue's three targets
  wp        the work-precision studies (configs/work_precision.yaml, work_precision_double.yaml,
            long_horizon.yaml) through `vcirun study` (vcirun.experiments.studies), with their figures; the
            10x target is read on vcirun's front (best method at each accuracy) of the two T = 5 studies

  tiers     first results in seconds (bench/tiers.py): `make run` in a fresh clone, the first CLI
            simulate of MCVAA and of the rocking block on an empty cache, the fig4 sweep on an empty
            cache on the auto tier against the compiled one (today's pipeline), the compiled tier's
            loop and call against /work/main

  friction  the frictional impact law (bench/friction_bench.py): the energy change of 10^4 random
            frictional impacts (target: no gain) and microseconds per impact against impact_law for
            k = 1, 2, 8, 50 contacts, coupled and uncoupled

  friction_scenes  friction in the integrators against the closed forms (bench/friction_scenes.py): a
            block held on a ramp for 10 s (with MuJoCo's creep where mujoco imports), Capobianco's
            spinning ball, the incline, the Coulomb oscillator's order, the cost of a held step with
            friction against one without

  loop      the engine loop's targets, this tree against a base tree (VCIRUN_BENCH_BASE, default /work/main;
            bench/loop_targets.py): compiled loop and whole simulate() against a hand-written numba CVA
            loop (bench/handwritten_cva.py), newton_cradle_100 us per smooth step, a cold first simulation

  throughput the target table of sweeps at the speed of the compiled loop (bench/throughput.py):
            simulate() against its loop, an ensemble of 10^5 runs against the loop time per core, the
            fig4 sweep against today's tree (/work/base) and a first simulate against the tree before
            the shared build (/work/preshared), in this one run

The machine is shared with other sessions: every timing is a median over repeats, the load average
is recorded at start and end, and ratios are formed from timings taken in this one run.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

import vcirun  # noqa: E402
from vcirun.core.grid import GridWarning  # noqa: E402
from friction_bench import section_friction  # noqa: E402 (bench/friction_bench.py: the section's rows)
from friction_scenes import section_friction_scenes  # noqa: E402 (bench/friction_scenes.py)
from throughput import section_throughput  # noqa: E402 (bench/throughput.py: the section's rows)
from tiers import section_tiers  # noqa: E402 (bench/tiers.py: first results in seconds)

METHODS = ["CVA", "VCI", "MCVAA", "MCVAC"]
PAPER_TABLE2 = {"MCVAA": {3.2e-2: (2.71, 0.61), 1e-2: (2.40, 0.39)},
                "MCVAC": {3.2e-2: (1.55, 0.33), 1e-2: (1.85, 0.22)}}   # seconds, mean +- 95% CI, T = 5
TARGETS = {"svc_step_us": 2.0, "cva_vci_5s_ms": 0.7, "mcva_5s_ms": 10.0, "fig4_warm_s": 15.0, "ratio": 10.0,
           "warm_start_s": 1.0}
QUICK = False


def log(msg=""):
    print(msg, flush=True)


def fit_exponent(x, y) -> float:
    x, y = np.asarray(x, float), np.asarray(y, float)
    m = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if m.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(x[m]), np.log(y[m]), 1)[0])


def median_walls(fn, repeats):
    """(median compiled-loop wall time, median call wall time, median call CPU time, last result)."""
    walls, calls, cpus = [], [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        tr = fn()
        cpus.append(time.thread_time() - c0)
        calls.append(time.perf_counter() - t0)
        walls.append(tr.wall_time)
    return statistics.median(walls), statistics.median(calls), statistics.median(cpus), tr


def probe(args: dict, cache_dir, timeout=1800) -> dict:
    """Run bench/_probe.py in a fresh process with VCIRUN_CACHE_DIR=cache_dir; also its outside wall."""
    env = dict(os.environ, VCIRUN_CACHE_DIR=str(cache_dir))
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, str(ROOT / "bench" / "_probe.py"), json.dumps(args)], env=env,
                           capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"args": args, "timeout_s": timeout, "error": f"timed out after {timeout} s"}
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        return {"args": args, "error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}"}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["process_wall_s"] = wall
    return out


# --- steps ------------------------------------------------------------------------------------------
def section_steps(res):
    log("== microseconds per smooth step (cart-pendulum, median of 7; CPU time of long runs, wall beside)")
    out = {}
    N = 20_000 if QUICK else 100_000
    for ld in ["SVC", "SVA"]:
        vcirun.simulate("cart_pendulum", ld, h=1e-3, T=0.01, beta=3.2, constrained=False)
        w, _, c, tr = median_walls(lambda: vcirun.simulate("cart_pendulum", ld, h=1e-3, T=N * 1e-3, beta=3.2,
                                                           constrained=False), 7)
        out[ld] = {"us": c / N * 1e6, "us_wall": w / N * 1e6, "newton_iters": float(tr.newton_iters.mean()),
                   "context": "constraint ignored, h=1e-3"}
        log(f"  {ld:6s} (constraint ignored, h = 1e-3)          {c / N * 1e6:7.3f} us CPU ({w / N * 1e6:7.3f} wall)"
            f"   Newton iters/step {tr.newton_iters.mean():.2f}")
    h, T = 1e-5, 0.7   # first impact at t = 0.729
    Nc = int(round(T / h))
    for m in METHODS:
        vcirun.simulate("cart_pendulum", m, h=h, T=10 * h, beta=3.2)
        w, _, c, tr = median_walls(lambda: vcirun.simulate("cart_pendulum", m, h=h, T=T, beta=3.2), 3 if QUICK else 7)
        assert len(tr.impacts) == 0
        out[m] = {"us": c / Nc * 1e6, "us_wall": w / Nc * 1e6, "newton_iters": float(tr.newton_iters.mean()),
                  "context": "constrained loop, before the first impact, h=1e-5"}
        log(f"  {m:6s} (constrained loop, no impact, h = 1e-5) {c / Nc * 1e6:7.3f} us CPU ({w / Nc * 1e6:7.3f} wall)"
            f"   Newton iters/step {tr.newton_iters.mean():.2f}")
    res["smooth_step_us"] = out


# --- sim5 -------------------------------------------------------------------------------------------
def section_sim5(res):
    log("== ms per 5-second simulation (cart-pendulum, beta = 3.2, median of 21)")
    out = {}
    log(f"  {'method':6s} {'h':>7s} {'loop ms':>9s} {'call ms':>9s} {'call CPU':>9s} {'impacts':>7s} {'steps':>6s}"
        "   paper Table II (s), paper / ours")
    for m in METHODS:
        for h in [1e-2, 3.2e-2]:
            w, c, cpu, tr = _sim5(m, h)
            paper = PAPER_TABLE2.get(m, {}).get(h)
            out[f"{m}@{h:g}"] = {"loop_ms": w * 1e3, "call_ms": c * 1e3, "call_cpu_ms": cpu * 1e3,
                                 "impacts": int(len(tr.impacts)), "steps": tr.n_steps, "paper_s": paper}
            ps = f"{paper[0]:.2f} +- {paper[1]:.2f} (x{paper[0] / w:,.0f})" if paper else ""
            log(f"  {m:6s} {h:7g} {w * 1e3:9.3f} {c * 1e3:9.3f} {cpu * 1e3:9.3f} {len(tr.impacts):7d} {tr.n_steps:6d}   {ps}")
    res["sim_5s"] = out


def _sim5(m, h):
    """(loop, call, call CPU, trajectory) of the 5 s run; h = 3.2e-2 ends the grid at N h = 4.992 as in
    the paper (the table's steps column shows N), so its GridWarning is not shown here."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GridWarning)
        vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=3.2)
        return median_walls(lambda: vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=3.2), 7 if QUICK else 21)


# --- impact -----------------------------------------------------------------------------------------
def _impact_driver(mod):
    from numba import njit

    integ = mod.integrate

    @njit
    def drive(K, q0, p0, t0, h, prm, ntol, maxit, etol, mis, Q, P, Hs, Eds, Hm, it, iq, ipm, ipp, ist, pl, il, info):
        for _ in range(K):
            integ(q0, p0, t0, h, 1, prm, True, ntol, maxit, etol, mis, Q, P, Hs, Eds, Hm, it, iq, ipm, ipp, ist, pl,
                  il, info)
        return info[2]

    return drive


def section_impact(res):
    from vcirun.run.resolve import resolve_system
    from vcirun.codegen.build import load_module
    from vcirun.methods.table import METHODS as MT

    log("== cost of one impact (instrumented: compiled loop over one impact step vs one smooth step; CPU time; "
        "an N = 1 call of the loop also allocates its work arrays and evaluates the energies of the end state)")
    s = resolve_system("cart_pendulum")
    prm = s.param_values(None)
    out = {}
    K = 2000 if QUICK else 20000
    for m in METHODS:
        mod = load_module(s, MT[m].kernel_set())
        drive = _impact_driver(mod)
        for h in [1e-2, 1e-3]:
            tr = vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=3.2)
            ks = np.flatnonzero(tr.impact_step)
            n = s.n
            buf = dict(Q=np.zeros((2, n)), P=np.zeros((2, n)), Hs=np.zeros(2), Eds=np.zeros(2), Hm=np.zeros(2),
                       it=np.zeros(64), iq=np.zeros((64, n)), ipm=np.zeros((64, n)), ipp=np.zeros((64, n)),
                       ist=np.zeros(1, np.bool_), pl=np.zeros(160), il=np.zeros(1, np.int64), info=np.zeros(5, np.int64))
            args = (1e-12, 50, 1e-13, 64)
            per_imp, per_smooth = [], []
            for k in ks:
                ksm = k - 3   # a smooth step shortly before
                for kk, acc in ((k, per_imp), (ksm, per_smooth)):
                    q0, p0 = tr.q[kk].copy(), tr.p[kk].copy()
                    drive(10, q0, p0, kk * h, h, prm, *args, *buf.values())
                    ts = []
                    for _ in range(7):
                        t0 = time.thread_time()
                        drive(K, q0, p0, kk * h, h, prm, *args, *buf.values())
                        ts.append((time.thread_time() - t0) / K)
                    acc.append(statistics.median(ts))
                    if kk == k:
                        assert buf["info"][2] == 1, "expected one impact in the step"
            imp = statistics.median(per_imp) * 1e6
            smo = statistics.median(per_smooth) * 1e6
            out[f"{m}@{h:g}"] = {"impact_step_us": imp, "smooth_step_us": smo, "impact_cost_us": imp - smo,
                                 "n_impacts_sampled": len(ks), "newton_iters_impact_steps": tr.newton_iters[ks].tolist()}
            log(f"  {m:6s} h = {h:<6g} impact step {imp:7.2f} us, smooth step {smo:6.3f} us -> one impact costs "
                f"{imp - smo:6.2f} us ({(imp - smo) / smo:.0f} smooth steps); Newton iterations in the impact steps "
                f"{tr.newton_iters[ks].tolist()}")
    res["impact"] = out


# --- build ------------------------------------------------------------------------------------------
def section_build(res):
    log("== kernel build, cold (fresh cache, new process) and warm (second process, same cache)")
    out = {}
    methods = ["CVA"] if QUICK else METHODS
    log(f"  {'method':6s} {'cold first sim':>14s} {'symbolic':>9s} {'numba':>7s} | {'warm import':>11s} "
        f"{'first sim':>9s} {'process':>8s}  symbolic modules on warm start")
    for m in methods:
        with tempfile.TemporaryDirectory(prefix="vcirun_bench_") as d:
            a = {"mode": "build", "system": "cart_pendulum", "method": m, "h": 1e-2, "T": 5.0, "beta": 3.2}
            cold = probe(a, d)
            warm = probe(a, d)
            fl = None
            if m == "CVA":  # the floor: the cached module loaded by path, nothing else imported
                from vcirun.codegen.build import module_key
                from vcirun.scenes.registry import get_scene
                from vcirun.methods.table import METHODS as MT

                key = module_key(get_scene("cart_pendulum"), MT["CVA"].kernel_set())
                fl = probe({"mode": "floor", "module_path": str(Path(d) / "kernels" / f"vk_{key}.py"),
                            "module_name": f"vcirun_kernels_{key}"}, d)
        out[m] = {"cold": cold, "warm": warm}
        if fl is not None:
            out[m]["floor"] = fl
            if "error" not in fl:
                log(f"  (warm-start floor, CVA: numpy {fl['numpy_s']:.2f} s, + numba {fl['numba_s']:.2f} s, + cached module "
                    f"{fl['module_exec_s']:.2f} s, first 5-s simulation done at {fl['to_first_sim_s']:.2f} s; "
                    f"{fl['process_wall_s']:.2f} s with interpreter start; no sympy, no scipy)")
        if "error" in cold or "error" in warm:
            log(f"  {m}: {cold.get('error') or warm.get('error')}")
            continue
        numba_s = cold["first_sim_s"] - cold["generate_s"]
        out[m]["numba_s"] = numba_s
        sym = [k for k in ("derive_imported", "modified_derive_imported") if warm[k]]
        log(f"  {m:6s} {cold['first_sim_s']:13.2f}s {cold['generate_s']:8.2f}s {numba_s:6.2f}s | "
            f"{warm['import_s']:10.3f}s {warm['first_sim_s']:8.3f}s {warm['process_wall_s']:7.2f}s  "
            f"{'none' if not sym else ', '.join(sym)} (cached: {warm['cached']})")
    res["build"] = out


# --- sweep ------------------------------------------------------------------------------------------
def section_sweep(res):
    log("== `vcirun sweep configs/fig4.yaml` (408 runs + 51 references), subprocess, --force, every core")
    out = {}
    exe = str(Path(sys.executable).with_name("vcirun"))
    with tempfile.TemporaryDirectory(prefix="vcirun_sweep_") as d:
        env = dict(os.environ, VCIRUN_CACHE_DIR=str(Path(d) / "cache"))
        for phase in ["cold", "warm"]:
            cmd = [exe, "sweep", "configs/fig4.yaml", "--output", str(Path(d) / "fig4_bench.h5"), "--force", "--quiet"]
            t0 = time.perf_counter()
            r = subprocess.run(cmd, env=env, cwd=ROOT, capture_output=True, text=True, timeout=3600)
            wall = time.perf_counter() - t0
            line = (r.stdout.strip().splitlines() or [""])[0]
            out[phase] = {"wall_s": wall, "returncode": r.returncode, "summary": line}
            log(f"  {phase:5s} {wall:7.2f} s (process)   {line}")
    res["fig4_sweep"] = out


# --- yardsticks -------------------------------------------------------------------------------------
def section_yardstick(res):
    from plain_numpy import PlainCVA

    from vcirun.experiments.baselines import solve_ivp_run
    from vcirun.experiments.workprecision import _front, time_at_error

    log("== the same work by plain numpy/scipy and by solve_ivp, at matched accuracy (beta = 3.2, T = 5)")
    out = {}
    ref = vcirun.reference("cart_pendulum", T=5.0, beta=3.2)
    P = PlainCVA()
    q0, p0 = P.s.initial_state(beta=3.2)
    # plain numpy step and CVA simulation (the same trajectory as vcirun's CVA)
    rows = {}
    for h in [1e-2, 3.2e-2]:
        N = int(round(5 / h))
        ts, cs = [], []
        for _ in range(3 if QUICK else 5):
            t0, c0 = time.perf_counter(), time.thread_time()
            Q, imp = P.simulate(q0, p0, h, N)
            cs.append(time.thread_time() - c0)
            ts.append(time.perf_counter() - t0)
        tr = vcirun.simulate("cart_pendulum", "CVA", h=h, T=5, beta=3.2)
        w, c, cpu, _ = median_walls(lambda: vcirun.simulate("cart_pendulum", "CVA", h=h, T=5, beta=3.2), 21)
        pw, pc = statistics.median(ts), statistics.median(cs)
        rows[h] = {"plain_ms": pw * 1e3, "plain_cpu_ms": pc * 1e3, "vcirun_loop_ms": w * 1e3, "vcirun_call_ms": c * 1e3,
                   "vcirun_call_cpu_ms": cpu * 1e3, "max_abs_diff_q": float(np.max(np.abs(Q - tr.q))),
                   "ratio_loop": pw / w, "ratio_call": pw / c, "ratio_cpu": pc / cpu}
        log(f"  plain numpy/scipy CVA, h = {h:<6g}: {pw * 1e3:8.2f} ms ({pc * 1e3:.2f} CPU) vs vcirun {w * 1e3:.3f} ms"
            f" loop / {c * 1e3:.3f} ms call ({cpu * 1e3:.3f} CPU) -> x{pw / w:.0f} / x{pw / c:.0f} (CPU x{pc / cpu:.0f}) "
            f"(same trajectory: max |dq| = {rows[h]['max_abs_diff_q']:.1e})")
    out["plain_cva"] = rows
    # solve_ivp curves on the same grids
    rtols = [10.0 ** -k for k in range(1, 13)]
    curves = {}
    for solver, kern in [("DOP853", "compiled"), ("DOP853", "numpy"), ("Radau", "compiled")]:
        for h in [1e-2, 3.2e-2]:
            pts = []
            for rtol in rtols:
                if solver == "Radau" and rtol < 1e-10:
                    continue
                b = solve_ivp_run("cart_pendulum", solver, h=h, T=5, beta=3.2, rtol=rtol, kernels=kern, energies=False)
                ws, cs, us = [], [], []
                for _ in range(3 if QUICK else (5 if solver == "DOP853" else 3)):
                    t0, c0 = time.perf_counter(), time.thread_time()
                    bb = solve_ivp_run("cart_pendulum", solver, h=h, T=5, beta=3.2, rtol=rtol, kernels=kern,
                                       energies=False)
                    us.append(time.thread_time() - c0)
                    cs.append(time.perf_counter() - t0)
                    ws.append(bb.wall_time)
                e = vcirun.l2_error(b, ref) if b.status == "ok" else math.nan
                pts.append({"rtol": rtol, "l2": e, "loop_ms": statistics.median(ws) * 1e3,
                            "call_ms": statistics.median(cs) * 1e3, "cpu_ms": statistics.median(us) * 1e3,
                            "nfev": b.options["nfev"]})
            curves[f"{solver}/{kern}@{h:g}"] = pts
    out["solve_ivp_curves"] = curves
    log("  solve_ivp L2 error and loop ms over rtol 1e-1..1e-12 on the h = 1e-2 grid:")
    for key in ("DOP853/compiled@0.01", "DOP853/numpy@0.01", "Radau/compiled@0.01"):
        log(f"    {key:22s} " + "  ".join(f"{p['rtol']:.0e}:{p['l2']:.1e}/{p['loop_ms']:.1f}" for p in curves[key]))
    matched = {}
    tt = np.linspace(0.0, 5.0, 20001)
    lost = 0.1 * float(np.sqrt((tt[1] - tt[0]) * np.sum(np.asarray(ref(tt)) ** 2)))   # 10 % of ||q_ref||_L2
    out["lost_threshold"] = lost
    log(f"  (solve_ivp runs with L2 error > {lost:.2g} = 10 % of ||q_ref|| have lost the motion and are not matched; "
        "<= : solve_ivp's cheapest run that keeps the motion is already more accurate)")
    log(f"  {'method':6s} {'h':>6s} {'L2 error':>9s} {'vcirun ms':>9s} {'CPU ms':>7s} | solve_ivp loop ms at that error "
        "(ratio of loop times; of CPU times): DOP853 compiled rhs, DOP853 numpy rhs, Radau compiled rhs")
    for m in METHODS:
        for h in [1e-2, 3.2e-2]:
            tr = vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=3.2)
            e = vcirun.l2_error(tr, ref)
            w, c, cpu, _ = median_walls(lambda: vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=3.2), 21)
            row = {"l2": e, "loop_ms": w * 1e3, "call_ms": c * 1e3, "cpu_ms": cpu * 1e3}
            cells = []
            for key in ("DOP853/compiled", "DOP853/numpy", "Radau/compiled"):
                pts = curves[f"{key}@{h:g}"]
                t, how = time_at_error(_front([(p["loop_ms"], p["l2"]) for p in pts if p["l2"] <= lost]), e)
                tc, howc = time_at_error(_front([(p["cpu_ms"], p["l2"]) for p in pts if p["l2"] <= lost]), e)
                row[key] = {"ms": t, "how": how, "ratio_loop": t / (w * 1e3), "cpu_ms": tc, "how_cpu": howc,
                            "ratio_cpu": tc / (cpu * 1e3)}
                mark = "<=" if how == "cheapest_more_accurate" else ">=" if how == "not_reached" else ""
                cells.append(f"{t:7.2f} ({mark}x{t / (w * 1e3):.1f}; x{tc / (cpu * 1e3):.1f})")
            matched[f"{m}@{h:g}"] = row
            log(f"  {m:6s} {h:6g} {e:9.2e} {w * 1e3:9.3f} {cpu * 1e3:7.3f} | " + "  ".join(cells))
    out["matched"] = matched
    res["yardstick"] = out


# --- scaling ----------------------------------------------------------------------------------------
def section_scaling(res):
    out = {}
    log("== scaling")
    # T
    Ts = [5, 50, 500] if QUICK else [5, 50, 500, 5000]
    rowsT = {}
    for m in ["CVA", "MCVAC"]:
        ws = []
        for T in Ts:
            _, _, w, tr = median_walls(lambda: vcirun.simulate("cart_pendulum", m, h=1e-2, T=T, beta=3.2),
                                       5 if T < 5000 else 3)
            ws.append(w)
            rowsT.setdefault(m, []).append({"T": T, "cpu_s": w, "impacts": int(len(tr.impacts)), "status": tr.status})
        log(f"  cost vs T, {m} h = 1e-2 (CPU per call): " + ", ".join(f"T={T}: {w * 1e3:.3g} ms" for T, w in zip(Ts, ws))
            + f"  -> exponent {fit_exponent(Ts, ws):.3f}")
        rowsT[m + "_exponent"] = fit_exponent(Ts, ws)
    out["T"] = rowsT
    # 1/h
    hs = [1e-1, 3.2e-2, 1e-2, 3.2e-3, 1e-3, 3.2e-4, 1e-4]
    rowsh = {}
    for m in METHODS:
        ws, st = [], []
        for h in hs:
            vcirun.simulate("cart_pendulum", m, h=h, T=10 * h, beta=3.2)
            _, _, w, tr = median_walls(lambda: vcirun.simulate("cart_pendulum", m, h=h, T=5, beta=3.2), 5)
            ws.append(w)
            st.append(tr.status)
        inv = [1 / h for h in hs]
        rowsh[m] = {"h": hs, "cpu_s": ws, "status": st, "exponent": fit_exponent(inv, ws),
                    "exponent_h<=1e-2": fit_exponent(inv[2:], ws[2:])}
        log(f"  cost vs 1/h, {m}, T = 5 (CPU per call): " + ", ".join(f"{w * 1e3:.3g}" for w in ws) + " ms  -> exponent "
            f"{rowsh[m]['exponent']:.3f} (h <= 1e-2: {rowsh[m]['exponent_h<=1e-2']:.3f})")
    out["inv_h"] = rowsh
    # impacts: oscillator against a wall at fixed N (h = 1e-2, T = 100), the wall moved towards the turning
    # point x = 1 so that the bounces get shorter: 24 .. ~1100 impacts
    ds = [0.5, 0.0, -0.5, -0.9, -0.97, -0.99, -0.997, -0.999]
    rowsi = {}
    for m in METHODS:
        ws, ni = [], []
        for d in ds:
            kw = dict(h=1e-2, T=100.0, q0=np.array([1.0]), p0=np.array([0.0]), params={"d": d})
            vcirun.simulate("oscillator_wall", m, **{**kw, "T": 0.01})
            _, _, w, tr = median_walls(lambda: vcirun.simulate("oscillator_wall", m, **kw), 5)
            ws.append(w)
            ni.append(len(tr.impacts) if tr.status == "ok" else math.nan)
        ni_a, ws_a = np.array(ni, float), np.array(ws)
        ok = np.isfinite(ni_a)
        slope, icpt = np.polyfit(ni_a[ok], ws_a[ok], 1)
        rowsi[m] = {"d": ds, "impacts": ni, "cpu_s": ws, "us_per_impact": slope * 1e6, "smooth_ms": icpt * 1e3,
                    "exponent_extra_vs_impacts": fit_exponent(ni_a[ok], ws_a[ok] - icpt)}
        log(f"  cost vs impacts, {m}, oscillator, h = 1e-2, 1e4 steps (CPU per call): impacts {[int(x) if np.isfinite(x) else 'fail' for x in ni]}"
            f" -> {', '.join(f'{w * 1e3:.3g}' for w in ws)} ms; linear fit {slope * 1e6:.2f} us per impact + "
            f"{icpt * 1e3:.3g} ms (exponent of the impact part {rowsi[m]['exponent_extra_vs_impacts']:.2f})")
    out["impacts"] = rowsi
    # mh_order: generalized MCVA on SVC, flow_order 4, cold builds
    orders = [1, 2, 3] if QUICK else [1, 2, 3, 4]
    rowsm = []
    for s in orders:
        mo = {"ld": "SVC", "mh_order": s, "flow_order": 4}
        with tempfile.TemporaryDirectory(prefix="vcirun_bench_") as d:
            a = {"mode": "build", "system": "cart_pendulum", "method": "MCVA", "method_options": mo, "h": 1e-2,
                 "T": 5.0, "beta": 3.2, "measure_steps": 20000, "measure_h": 1e-3, "measure_sim": True}
            cold = probe(a, d, timeout=1800)
            warm = probe(a, d)
        row = {"mh_order": s, "cold": cold, "warm": warm}
        if "error" not in cold and "error" not in warm:
            row.update(symbolic_s=cold["generate_s"], numba_s=cold["first_sim_s"] - cold["generate_s"],
                       us_per_step=warm["us_per_step"], sim5_cpu_ms=warm["sim_cpu_ms"], sim5_loop_ms=warm["sim_loop_ms"])
            log(f"  MCVA[SVC, s={s}, p=4]: symbolic {cold['generate_s']:.2f} s, numba {row['numba_s']:.1f} s, "
                f"{warm['us_per_step']:.3f} us per smooth step (constraint ignored); 5 s simulation at h = 1e-2 "
                f"{warm['sim_loop_ms']:.3f} ms loop, {warm['sim_cpu_ms']:.3f} ms CPU per call, {warm['sim_impacts']} impacts, "
                f"status {warm['sim_status']}")
        else:
            log(f"  MCVA[SVC, s={s}]: {cold.get('error') or warm.get('error')}")
        rowsm.append(row)
    ok = [r for r in rowsm if "us_per_step" in r]
    if len(ok) >= 2:
        out["mh_order_exponents"] = {k: fit_exponent([r["mh_order"] for r in ok], [r[k] for r in ok])
                                     for k in ("symbolic_s", "numba_s", "us_per_step", "sim5_cpu_ms")}
        log("  exponents vs mh_order: " + ", ".join(f"{k} {v:.2f}" for k, v in out["mh_order_exponents"].items()))
    out["mh_order"] = rowsm
    out["dof"] = dof_rows()
    res["scaling"] = out


def section_dof(res):
    """The degrees-of-freedom part of `scaling` alone (saved as res["scaling_dof"])."""
    log("== scaling with the degrees of freedom")
    res["scaling_dof"] = dof_rows()


def dof_rows() -> dict:
    """n-link pendulum against a wall, n = 1, 2, 4, 8: cold builds (symbolic, numba), us per step."""
    Ks = [1, 2, 4] if QUICK else [1, 2, 4, 8]
    rowsk = {}
    for m in ["CVA", "MCVAC", "MCVAA"]:
        rows = []
        for K in Ks:
            with tempfile.TemporaryDirectory(prefix="vcirun_bench_") as d:
                a = {"mode": "build", "system": f"n_pendulum_{K}", "method": m, "h": 1e-3, "T": 0.01,
                     "measure_steps": 20000, "measure_h": 1e-3}
                cold = probe(a, d, timeout=2400)
                warm = probe(a, d) if "error" not in cold else {"error": "cold build failed"}
            row = {"K": K, "cold": cold, "warm": warm}
            if "error" not in cold and "error" not in warm:
                row.update(symbolic_s=cold["generate_s"], numba_s=cold["first_sim_s"] - cold["generate_s"],
                           us_per_step=warm["us_per_step"], newton_iters=warm["measure_newton_iters"])
                log(f"  n_pendulum_{K} {m}: symbolic {row['symbolic_s']:.2f} s, numba {row['numba_s']:.1f} s, "
                    f"{row['us_per_step']:.3f} us per smooth step (h = 1e-3, {row['newton_iters']:.1f} Newton iters)")
            else:
                log(f"  n_pendulum_{K} {m}: {cold.get('error') or warm.get('error')}")
            rows.append(row)
        ok = [r for r in rows if "us_per_step" in r]
        exps = {k: fit_exponent([r["K"] for r in ok], [r[k] for r in ok]) for k in ("symbolic_s", "numba_s", "us_per_step")}
        rowsk[m] = {"rows": rows, "exponents": exps}
        log(f"  exponents vs n ({m}): " + ", ".join(f"{k} {v:.2f}" for k, v in exps.items()))
    return rowsk


# --- work-precision ----------------------------------------------------------------------------------
def section_wp(res):
    import io

    from vcirun.experiments.studies.runner import run_file

    out = {}
    for cfg in ["configs/work_precision.yaml", "configs/work_precision_double.yaml", "configs/long_horizon.yaml"]:
        log(f"== work-precision study {cfg}")
        t0 = time.perf_counter()
        tables = io.StringIO()
        try:   # the study API (what `vcirun study CFG --plot [--quick]` runs), in this process
            run = run_file(ROOT / cfg, plot=True, quick=QUICK, log=log, tables=tables,
                           output=ROOT / "results" / (Path(cfg).stem + ("_quick" if QUICK else "") + ".json"))
            log(tables.getvalue().rstrip())
            out[cfg] = {"returncode": 0, "results": str(run.results), "seconds": time.perf_counter() - t0}
        except Exception as e:  # noqa: BLE001 - one study failing must not end the benchmark
            log(f"  failed: {type(e).__name__}: {e}")
            out[cfg] = {"returncode": 1, "error": f"{type(e).__name__}: {e}", "seconds": time.perf_counter() - t0}
    res["work_precision"] = out


def print_targets(res):
    log("== performance targets (measured in this run)")
    rows = []
    st = res.get("smooth_step_us", {})
    if "SVC" in st:
        rows.append(("smooth SVC step (constraint ignored)", f"{st['SVC']['us']:.3f} us", "<= 2 us",
                     st["SVC"]["us"] <= TARGETS["svc_step_us"]))
    if "CVA" in st:
        rows.append(("smooth CVA step in the constrained loop", f"{st['CVA']['us']:.3f} us", "<= 2 us",
                     st["CVA"]["us"] <= TARGETS["svc_step_us"]))
    s5 = res.get("sim_5s", {})
    for m in METHODS:
        k = f"{m}@0.01"
        if k in s5:
            lim = TARGETS["cva_vci_5s_ms"] if m in ("CVA", "VCI") else TARGETS["mcva_5s_ms"]
            rows.append((f"5 s {m} simulation, h = 1e-2 (loop / call)",
                         f"{s5[k]['loop_ms']:.3f} / {s5[k]['call_ms']:.3f} ms", f"<= {lim:g} ms",
                         s5[k]["call_ms"] <= lim))
    sw = res.get("fig4_sweep", {})
    if "warm" in sw:
        rows.append(("fig4 sweep warm, 2 cores", f"{sw['warm']['wall_s']:.2f} s", "< 15 s",
                     sw["warm"]["wall_s"] < TARGETS["fig4_warm_s"]))
    b = res.get("build", {})
    if "CVA" in b and "process_wall_s" in b["CVA"].get("warm", {}):
        w = b["CVA"]["warm"]
        sym = w["derive_imported"] or w["modified_derive_imported"]
        rows.append(("warm start to the first finished simulation (process)",
                     f"{w['to_first_sim_s']:.3f} s in-process, {w['process_wall_s']:.2f} s with interpreter start; "
                     f"symbolic: {'yes' if sym else 'no'}", "< 1 s, no symbolic work",
                     w["process_wall_s"] < 1.0 and not sym))
    sfx = "_quick" if QUICK else ""
    for name, path in (("cart-pendulum", f"results/work_precision{sfx}.json"),
                       ("double pendulum", f"results/work_precision_double{sfx}.json")):
        if "work_precision" not in res or not (ROOT / path).exists():
            continue
        front = json.loads((ROOT / path).read_text()).get("front") or []
        for solver in ("DOP853", "DOP853/numpy"):
            vals = [(r.get(f"{solver}_call_ratio"), r.get(f"{solver}_call_how")) for r in front]
            vals = [(v, how) for v, how in vals if v is not None and how in ("interpolated", "not_reached")]
            if vals:
                lo = min(v for v, _ in vals)
                rows.append((f"{name}: {solver} / vcirun front, whole call, min over accuracy levels",
                             f"x{lo:.1f} .. x{max(v for v, _ in vals):.1f} ({len(vals)} levels)", ">= x10", lo >= 10))
    ref = res.get("reference", {})
    if "box" in ref:
        rows.append(("random box states with a wrong event sequence (reference)",
                     f"{ref['box']['wrong'] + ref['box']['failed']} of {ref['box']['states']}", "0",
                     ref["box"]["wrong"] + ref["box"]["failed"] == 0))
    if "cart_ratio" in ref:
        c = ref["cart_ratio"]
        rows.append(("cart-pendulum reference, warm, vs one MCVAA simulate()",
                     f"{c['reference_ms']:.2f} / {c['mcvaa_ms']:.2f} ms = {c['ratio']:.1f}x", "<= 4x", c["ratio"] <= 4.0))
    if "independent" in ref:
        e = ref["independent"]["cart_taylor_max"]
        rows.append(("reference error against an independent solve (cart-pendulum)", f"{e:.1e}", "<= 1e-12", e <= 1e-12))
    tl = res.get("tolerance")
    if tl:
        rows.append(("tol=: runs said ok whose true L2 error exceeds tol",
                     f"{tl['over_tol']} of {tl['ok_runs']} ({100 * tl['over_tol_fraction']:.1f} %), worst "
                     f"{tl['worst_over']:.2f}x", "<= 5 %, none > 3x",
                     tl["over_tol_fraction"] <= 0.05 and not tl["worst_over"] > 3))
        rows.append(("tol=: CPU of the call / cheapest (method, h) meeting tol",
                     f"median {tl['cost_ratio_median']:.2f}, p90 {tl['cost_ratio_p90']:.2f}", "<= 2x",
                     tl["cost_ratio_p90"] <= 2))
        rows.append(("estimates unresolved where the impacts differ from the reference's",
                     f"{tl['flagged_unresolved']} of {tl['sequence_differs']}", "100 %",
                     tl["flagged_unresolved"] == tl["sequence_differs"]))
    for name, val, tgt, ok in rows:
        log(f"  {name:58s} {val:48s} target {tgt:24s} {'MET' if ok else 'not met'}")
    res["targets"] = [{"what": a, "measured": b_, "target": c, "met": bool(d)} for a, b_, c, d in rows]


def section_coldbuild(res):
    import coldbuild

    log("== cold builds (fresh cache, fresh process, one at a time; stages in CPU seconds)")
    cases = (["cart_pendulum:CVA+core", "cart_pendulum:MCVAC+core"] if QUICK else coldbuild.DEFAULT_CASES)
    log("  (SCENE:METHOD+core: the method's shared core (vcirun.codegen.shared) compiled first by another scene in the "
        "same fresh cache, once per machine; without +core nothing is cached, the core is compiled too)")
    rows = {}
    coldbuild.header(log=log)
    for c in cases:
        r = coldbuild.run_case(c)
        rows[f"default/{c}"] = r
        coldbuild.print_row(r, log=log)
    for key, r in rows.items():
        coldbuild.print_kernels(r, 5, log=log)
    log("  cold-build targets (the scene, fresh scene cache): case, the specialized build's figure, core cached, "
        "nothing cached (wall / CPU s, load average before)")
    table = []
    for case, (today, target) in coldbuild.TARGETS.items():
        d, nothing = rows.get(f"default/{case}+core"), rows.get(f"default/{case}")
        cell = lambda r: ("-" if r is None or "error" in r else  # noqa: E731
                          f"{r['first_sim_s']:.1f} / {r['first_sim_cpu_s']:.1f} (load {r['loadavg_before'][0]:.1f})")
        met = None if d is None or "error" in d else bool(d["first_sim_s"] <= target)
        met_cpu = None if d is None or "error" in d else bool(d["first_sim_cpu_s"] <= target)
        table.append({"case": case, "today_s": today, "target_s": target, "core_cached": cell(d),
                      "nothing_cached": cell(nothing), "met_wall": met, "met_cpu": met_cpu})
        log(f"    {case:22s} today {today:6.1f} s  target <= {target:4.0f} s | core cached {cell(d):28s} "
            f"{'not measured' if met is None else 'met' if met else 'met in CPU time' if met_cpu else 'NOT met'} | "
            f"nothing cached {cell(nothing)}")
    res["coldbuild"] = {"rows": rows, "targets": table}


# --- contacts -----------------------------------------------------------------------------------------
_CART_YAML = {"coordinates": ["y", "theta"], "parameters": {"m1": 1.0, "m2": 0.2, "L": 2.0, "g": 10.0},
              "mass_matrix": [["m1 + m2", "m2*L*sin(theta)"], ["m2*L*sin(theta)", "m2*L**2"]],
              "potential": "(m1 + m2)*g*y - m2*g*L*cos(theta)"}


def section_contacts(res):
    """us per step with one constraint and with an added inactive one (the acceptance check).

    The one- and two-constraint runs alternate (pairs), and the added cost is the median of the
    paired differences: a slow spell of the shared machine hits both members of a pair, where
    separate medians of each (the first version of this section) let it through as +-0.2 us of noise.
    """
    from vcirun.mechanics.loader import load_system_yaml

    pairs = 7 if QUICK else 41
    log("== cost of an added inactive constraint (cart-pendulum in YAML, constrained loop before the first"
        f" impact, h = 1e-5, T = 0.2; CPU; median of {pairs} interleaved pairs)")
    one = load_system_yaml(_CART_YAML | {"name": "cart_one", "constraints": [{"name": "floor", "phi": "y"}]})
    two = load_system_yaml(_CART_YAML | {"name": "cart_two", "constraints": [{"name": "floor", "phi": "y"},
                                                                             {"name": "ceiling", "phi": "100 - y"}]})
    h, T = 1e-5, 0.2
    Nc = int(round(T / h))
    q0, p0 = np.array([3.2, 0.0]), np.array([0.0, 3.5 - 0.18 * 3.2])  # the scene's Xi(3.2)
    vcirun.simulate("cart_pendulum", "SVC", h=1e-3, T=0.01, beta=3.2, constrained=False)

    def cpu_us(fn):
        c0 = time.thread_time()
        tr = fn()
        return (time.thread_time() - c0) / Nc * 1e6, tr

    svc = [cpu_us(lambda: vcirun.simulate("cart_pendulum", "SVC", h=h, T=T, beta=3.2, constrained=False))[0]
           for _ in range(pairs)]
    svc_us = statistics.median(svc)
    log(f"  smooth SVC step (constraint ignored)       {svc_us:7.3f} us")
    out = {"svc_us": svc_us, "pairs": pairs, "loadavg_before": os.getloadavg()}
    for m in METHODS:
        for sysm in (one, two):
            vcirun.simulate(sysm, m, h=h, T=10 * h, q0=q0, p0=p0)
        ones, twos, diffs = [], [], []
        for k in range(pairs):
            order = (one, two) if k % 2 == 0 else (two, one)
            got = {}
            for sysm in order:
                us, tr = cpu_us(lambda: vcirun.simulate(sysm, m, h=h, T=T, q0=q0, p0=p0))
                assert len(tr.impacts) == 0 and tr.status == "ok"
                got[sysm.name] = us
            ones.append(got["cart_one"])
            twos.append(got["cart_two"])
            diffs.append(got["cart_two"] - got["cart_one"])
        q1, q3 = np.percentile(diffs, [25, 75])
        row = {"one": statistics.median(ones), "two": statistics.median(twos), "added_us": statistics.median(diffs),
               "added_iqr_us": [float(q1), float(q3)]}
        row["added_pct_of_svc"] = 100.0 * row["added_us"] / svc_us
        out[m] = row
        log(f"  {m:6s} one constraint {row['one']:7.3f} us, two {row['two']:7.3f} us: added "
            f"{row['added_us']:+.3f} us (IQR {q1:+.3f} .. {q3:+.3f}) = {row['added_pct_of_svc']:+.1f} % of a smooth step")
    out["loadavg_after"] = os.getloadavg()
    res["inactive_constraint"] = out


def section_cacheverify(res):
    log("== kernel cache checks on a warm start: checked against unchecked loads (bench/cache_verify.py)")
    import cache_verify

    r = cache_verify.measure(repeats=3 if QUICK else 9)
    cache_verify.report(r, log)
    res["cache_verify"] = r


def section_reference(res):
    """The exact reference: cost per scene (Taylor, DOP853) beside the methods, and its targets."""
    import reference_bench

    res["reference"] = reference_bench.main(["--quick"] if QUICK else [])


def section_tol(res):
    """simulate(tol=...) and tr.error_estimate() against the exact reference: bench/tolerance.py."""
    import tolerance

    res["tolerance"] = tolerance.main(["--quick"] if QUICK else [])["summary"]


def section_bodies(res):
    """Cradles of N = 3, 10, 30, 100 balls and link chains by bodies: bench/bodies_scaling.py."""
    import bodies_scaling

    out = ROOT / "results" / "bodies_scaling.json"
    bodies_scaling.main(["--cases", "newton_cradle_3,newton_cradle_10" if QUICK else bodies_scaling.DEFAULT,
                         "--out", str(out)])
    res["bodies"] = json.loads(out.read_text())


def section_loop(res):
    """The engine loop's targets against the base tree (bench/loop_targets.py)."""
    import loop_targets

    r = loop_targets.measure(Path(os.environ.get("VCIRUN_BENCH_BASE", "/work/main")),
                             ["yardstick", "kernels", "cradle", "coldbuild"], 41 if QUICK else 201,
                             ("shared", "specialized"))
    loop_targets.report(r, log=log)
    res["loop"] = r


SECTIONS = {"steps": section_steps, "sim5": section_sim5, "impact": section_impact, "build": section_build,
            "sweep": section_sweep, "yardstick": section_yardstick, "scaling": section_scaling, "dof": section_dof,
            "wp": section_wp, "coldbuild": section_coldbuild, "contacts": section_contacts,
             "bodies": section_bodies, "cacheverify": section_cacheverify,
             "throughput": lambda res: section_throughput(res, quick=QUICK), "reference": section_reference,
             "tiers": lambda res: section_tiers(res, quick=QUICK, log=log),
             "friction": lambda res: section_friction(res, quick=QUICK),
             "friction_scenes": lambda res: section_friction_scenes(res, quick=QUICK, log=log),
             "tol": section_tol,
             "loop": section_loop}


def main(argv=None):
    global QUICK
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=",".join(SECTIONS), help="comma-separated sections: " + ", ".join(SECTIONS))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--output", default=None)
    a = ap.parse_args(argv)
    QUICK = a.quick
    os.chdir(ROOT)
    # the rows time the compiled tier (a first call on cold kernels would run interpreted while they
    # compile in the background); the tiers section gives its own processes the auto tier
    os.environ.setdefault("VCIRUN_TIER", "compiled")
    # one build for every row (the auto build would switch a hot module to its specialized build mid-run)
    os.environ.setdefault("VCIRUN_BUILD", "shared")
    res = {"machine": {"cpus": len(os.sched_getaffinity(0)), "python": sys.version.split()[0],
                       "loadavg_start": list(os.getloadavg()), "started": time.strftime("%Y-%m-%d %H:%M:%S"),
                       "cache_dir": os.environ.get("VCIRUN_CACHE_DIR", "")},
           "quick": QUICK, "note": "shared machine: medians over repeats; ratios from timings of this run"}
    log(f"vcirun benchmark: {res['machine']['cpus']} cpus, load average {res['machine']['loadavg_start'][0]:.2f} "
        f"(shared machine: medians over repeats)")
    t0 = time.perf_counter()
    for name in a.only.split(","):
        name = name.strip()
        if name not in SECTIONS:
            raise SystemExit(f"unknown section {name!r} (choose from {', '.join(SECTIONS)})")
        SECTIONS[name](res)
    res["machine"]["loadavg_end"] = list(os.getloadavg())
    res["seconds"] = time.perf_counter() - t0
    out = Path(a.output or ("results/bench_all_quick.json" if QUICK else "results/bench_all.json"))
    out.parent.mkdir(exist_ok=True)
    from vcirun.experiments.studies.jsonio import to_json as _jsonable

    res = _jsonable(res)
    if out.exists() and a.only != ",".join(SECTIONS):   # a partial run updates the saved sections only
        try:
            old = json.loads(out.read_text())
            res["partial_runs"] = old.get("partial_runs", []) + [{"sections": a.only, "machine": res["machine"]}]
            res["machine"] = old.get("machine", res["machine"])
            old.update(res)
            res = old
            log("(targets below combine this run's sections with the saved ones)")
        except ValueError:
            pass
    print_targets(res)
    out.write_text(json.dumps(_jsonable(res), indent=1))
    log(f"saved {out} ({res['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
