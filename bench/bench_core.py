"""Core benchmarks (printed and saved as JSON; never asserted).

- microseconds per smooth step (SVC, SVA; cart-pendulum, constraint ignored), beside the same SVC
  step written in plain numpy/scipy (sympy.lambdify + numpy Newton), as a ratio from one run;
- ms per 5-second CVA / VCI simulation at h = 1e-2 and 3.2e-2 (beta = 3.2: three impacts);
- kernel build time cold (fresh cache, new process) and warm (second process): time to the first
  completed simulation, and whether the warm start did any symbolic work.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import sympy as sp

import vcirun
from vcirun.discrete.lagrangians import LIBRARY, step_expressions
from vcirun.scenes.registry import get_scene


def median_time(fn, repeat=7):
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def us_per_step(method, N=100_000):
    vcirun.simulate("cart_pendulum", method, h=1e-3, T=10 * 1e-3, beta=3.2, constrained=False)  # warm
    walls = [vcirun.simulate("cart_pendulum", method, h=1e-3, T=N * 1e-3, beta=3.2, constrained=False).wall_time
             for _ in range(5)]
    return statistics.median(walls) / N * 1e6


def numpy_svc_us_per_step(N=2000):
    """The same SVC step as a user would write it with numpy/scipy: lambdified slot derivatives and
    a numpy Newton loop (np.linalg.solve)."""
    s = get_scene("cart_pendulum")
    ex = step_expressions(s, LIBRARY["SVC"], need_energy=False)
    q0, v, h, t = ex["symbols"]
    args = (q0, v, h, t, s.param_symbols)
    Pm = sp.lambdify(args, ex["Pm"], "numpy")
    J = sp.lambdify(args, ex["Pm_v"], "numpy")
    Pp = sp.lambdify(args, ex["Pp"], "numpy")
    prm = list(s.param_values())
    q, p = s.initial_state(beta=3.2)
    Mf = sp.lambdify((s.q, s.param_symbols), s.M, "numpy")

    def run():
        nonlocal q, p
        qq, pp = q.copy(), p.copy()
        for _ in range(N):
            vv = np.linalg.solve(np.array(Mf(qq, prm), float), pp)
            for _ in range(50):
                r = np.array(Pm(qq, vv, 1e-3, 0.0, prm), float).ravel() - pp
                d = np.linalg.solve(np.array(J(qq, vv, 1e-3, 0.0, prm), float), r)
                vv = vv - d
                if np.max(np.abs(d)) <= 1e-12 * (1 + np.max(np.abs(vv))):
                    break
            pp = np.array(Pp(qq, vv, 1e-3, 0.0, prm), float).ravel()
            qq = qq + 1e-3 * vv

    return median_time(run, repeat=3) / N * 1e6


def ms_per_sim(method, h):
    vcirun.simulate("cart_pendulum", method, h=h, T=5, beta=3.2)
    walls, calls = [], []
    for _ in range(21):
        t0 = time.perf_counter()
        tr = vcirun.simulate("cart_pendulum", method, h=h, T=5, beta=3.2)
        calls.append(time.perf_counter() - t0)
        walls.append(tr.wall_time)
    return statistics.median(walls) * 1e3, statistics.median(calls) * 1e3, len(tr.impacts)


_PROBE = r"""
import time, sys
t0 = time.perf_counter()
import vcirun
from vcirun.codegen.kernel_cache import default
t1 = time.perf_counter()
with default().report() as built:
    tr = vcirun.simulate("cart_pendulum", sys.argv[1], h=1e-2, T=5, beta=3.2)
t2 = time.perf_counter()
print(t1 - t0, t2 - t1, int(built.entries[-1]["cached"]), int("sympy.core" in sys.modules and "vcirun.codegen.derive" in sys.modules))
"""


def build_times(method):
    with tempfile.TemporaryDirectory() as d:
        env = dict(os.environ, VCIRUN_CACHE_DIR=d)
        out = []
        for _ in range(2):
            r = subprocess.run([sys.executable, "-c", _PROBE, method], env=env, capture_output=True, text=True, check=True)
            imp, first, cached, symbolic = r.stdout.split()
            out.append({"import_s": float(imp), "first_sim_s": float(first), "cached": bool(int(cached)),
                        "symbolic_work": bool(int(symbolic))})
        return {"cold": out[0], "warm": out[1]}


def main():
    res = {"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]}}
    svc = us_per_step("SVC")
    sva = us_per_step("SVA")
    npy = numpy_svc_us_per_step()
    res["smooth_step_us"] = {"SVC": svc, "SVA": sva, "SVC_numpy": npy, "numpy_over_vcirun": npy / svc}
    print(f"smooth step (cart-pendulum): SVC {svc:.3f} us, SVA {sva:.3f} us; plain numpy SVC {npy:.1f} us "
          f"-> {npy / svc:.0f}x")
    res["sim_5s_ms"] = {}
    for m in ["CVA", "VCI"]:
        for h in [1e-2, 3.2e-2]:
            w, c, ni = ms_per_sim(m, h)
            res["sim_5s_ms"][f"{m}@{h:g}"] = {"integrate_ms": w, "call_ms": c, "impacts": ni}
            print(f"{m:5s} h={h:<7g} 5 s simulation: {w:.3f} ms in the compiled loop, {c:.3f} ms per simulate() call, {ni} impacts")
    res["build"] = {}
    for m in ["CVA"]:
        b = build_times(m)
        res["build"][m] = b
        print(f"{m} kernel build: cold first simulation {b['cold']['first_sim_s']:.2f} s; warm (second process) "
              f"{b['warm']['first_sim_s']:.3f} s, symbolic work on warm start: {b['warm']['symbolic_work']}")
    out = Path("results/bench_core.json")
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(res, indent=2))
    print(f"saved {out}")


if __name__ == "__main__":
    main()
