"""Subprocess probe of bench_all.py: one fresh process, timed from its first line.

    python bench/_probe.py '{"mode": "build", "system": "cart_pendulum", "method": "CVA", ...}'

mode "build": import vcirun, run one simulation (the first one compiles or loads the kernels),
  report import time, time to the first finished simulation, the symbolic/write time of the cache
  miss (the kernel cache's build report), whether any symbolic module was imported, and optionally the
  microseconds per step (CPU time of the call, wall beside) of a longer run with the constraint
  ignored, in the same process (warm kernels).
  With measure_sim, also the median loop and CPU time of the first simulation's settings.
mode "floor": the warm-start floor (see `floor`).
mode "derive": time `vcirun.codegen.derive.module_source` alone (no numba), and the source size.
Prints one JSON line.
"""
import time

T_START = time.perf_counter()
import json  # noqa: E402
import sys  # noqa: E402


def floor(a):
    """The warm-start floor: numpy + numba + the cached kernel module loaded by path (no sympy, no
    scipy, no vcirun import), then one 5-s cart-pendulum CVA run through its compiled loop."""
    import importlib.util

    import numpy as np

    t_np = time.perf_counter() - T_START
    import numba  # noqa: F401

    t_nb = time.perf_counter() - T_START
    spec = importlib.util.spec_from_file_location(a["module_name"], a["module_path"])
    mod = importlib.util.module_from_spec(spec)
    sys.modules[a["module_name"]] = mod
    spec.loader.exec_module(mod)
    t_mod = time.perf_counter() - T_START
    N, n, cap = 500, 2, 141
    q0, p0 = np.array([3.2, 0.0]), np.array([0.0, 0.2 * 2.0 ** 2 * (3.5 - 0.18 * 3.2)])  # Xi(3.2): p = M(q0) qdot0
    prm = np.array([1.0, 0.2, 2.0, 10.0])
    out = [np.zeros((N + 1, n)), np.zeros((N + 1, n)), np.zeros(N + 1), np.zeros(N + 1), np.zeros(N + 1), np.zeros(cap),
           np.zeros((cap, n)), np.zeros((cap, n)), np.zeros((cap, n)), np.zeros(N, np.bool_), np.zeros(2 * cap + 16),
           np.zeros(N, np.int64), np.zeros(5, np.int64)]
    mod.integrate(q0, p0, 0.0, 1e-2, N, prm, True, 1e-12, 50, 1e-13, 64, *out, True)  # the signature simulate compiled
    t_sim = time.perf_counter() - T_START
    print(json.dumps({"args": a, "numpy_s": t_np, "numba_s": t_nb, "module_exec_s": t_mod, "to_first_sim_s": t_sim,
                      "impacts": int(out[-1][2]), "sympy_imported": "sympy" in sys.modules,
                      "scipy_imported": "scipy" in sys.modules}))


def main():
    a = json.loads(sys.argv[1])
    if a["mode"] == "floor":
        floor(a)
        return
    import vcirun
    from vcirun.codegen import build

    t_import = time.perf_counter() - T_START
    mopts = a.get("method_options", {})
    out = {"args": a, "import_s": t_import}
    if a["mode"] == "derive":
        from vcirun.scenes.registry import get_scene  # symbolic: imported only in this mode
        from vcirun.methods.table import resolve_method

        s = get_scene(a["system"])
        ks = resolve_method(a["method"], **mopts).kernel_set()
        t0 = time.perf_counter()
        from vcirun.codegen.derive import module_source

        text = module_source(s, ks)
        out.update(derive_s=time.perf_counter() - t0, source_chars=len(text), source_lines=text.count("\n"))
        print(json.dumps(out))
        return
    kw = dict(h=a.get("h", 1e-2), T=a.get("T", 5.0), **mopts)
    if a.get("beta") is not None:
        kw["beta"] = a["beta"]
    if a.get("constrained") is not None:
        kw["constrained"] = a["constrained"]
    t0 = time.perf_counter()
    with default().report() as built:
        tr = vcirun.simulate(a["system"], a["method"], **kw)
    t1 = time.perf_counter()
    log = built.entries[-1] if built.entries else {}
    out.update(first_sim_s=t1 - t0, to_first_sim_s=t1 - T_START, cached=bool(log.get("cached")),
               generate_s=float(log.get("generate_s", float("nan"))), status=tr.status,
               derive_imported="vcirun.codegen.derive" in sys.modules,
               modified_derive_imported="vcirun.modified.eta" in sys.modules,
               sympy_imported="sympy" in sys.modules, n_impacts=int(len(tr.impacts)))
    m = a.get("measure_steps")
    if m:
        import statistics

        h = a.get("measure_h", 1e-3)
        walls, cpus = [], []
        for _ in range(a.get("measure_repeats", 5)):
            c0 = time.thread_time()
            r = vcirun.simulate(a["system"], a["method"], h=h, T=m * h, constrained=False, beta=a.get("beta"), **mopts)
            cpus.append((time.thread_time() - c0) / m * 1e6)
            walls.append(r.wall_time / m * 1e6)
        out.update(us_per_step=statistics.median(cpus), us_per_step_wall=statistics.median(walls),
                   us_per_step_all=cpus, measure_status=r.status, measure_newton_iters=float(r.newton_iters.mean()))
    if a.get("measure_sim"):
        import statistics

        walls, cpus = [], []
        for _ in range(a.get("measure_sim_repeats", 11)):
            c0 = time.thread_time()
            r = vcirun.simulate(a["system"], a["method"], **kw)
            cpus.append(time.thread_time() - c0)
            walls.append(r.wall_time)
        out.update(sim_loop_ms=statistics.median(walls) * 1e3, sim_cpu_ms=statistics.median(cpus) * 1e3,
                   sim_status=r.status, sim_impacts=int(len(r.impacts)))
    print(json.dumps(out))


if __name__ == "__main__":
    main()
