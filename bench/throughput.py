"""`make bench` section `throughput`: the target table of sweeps at the speed of the compiled loop,
every row measured in this one run (ratios from timings taken side by side).

Rows:
  simulate   `vcirun.simulate()` call against its own compiled loop (`traj.wall_time`), CVA
             cart-pendulum, h = 1e-2, T = 5, beta = 3.2: medians of interleaved calls
  ensemble   `vcirun.ensemble` of k CVA cart-pendulum runs (final states; beta uniform in
             [3.2, 5.2]) against k x the median loop time of the same runs / the cores
  sweep      `vcirun sweep configs/fig4.yaml --force` computing (wall minus kernel preparation),
             this tree against BASE (a checkout of today's tree: --base, default /work/base), each
             in its own process with its own warm kernel cache, alternating; and whether the two
             files' L2 errors are equal to the bit
  first      the first `vcirun.simulate` of CVA with an empty kernel cache (fresh process, fresh
             cache dir), this tree against PRESHARED (the tree before the shared build: --preshared)
  makerun    `make run` in a fresh clone of this repository's HEAD (git clone; a new .venv, pip's
             own cache as it is, an empty kernel cache): its wall time and the time of each step

Run alone: python bench/throughput.py [--quick] [--k 100000] [--base DIR] [--preshared DIR]
[--rows simulate,ensemble,sweep,first,makerun] [--base-cache DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
TARGETS = {"simulate": 1.3, "ensemble": 1.5, "sweep": 0.15, "first": 2.0, "makerun": 80.0}


def log(msg=""):
    print(msg, flush=True)


def _cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def row_simulate(repeats: int) -> dict:
    import vcirun

    f = lambda: vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5, beta=3.2)  # noqa: E731
    for _ in range(20):
        f()
    calls, loops = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        tr = f()
        calls.append(time.perf_counter() - t)
        loops.append(tr.wall_time)
    c, w = statistics.median(calls), statistics.median(loops)
    return {"call_ms": c * 1e3, "loop_ms": w * 1e3, "ratio": c / w}


def row_ensemble(k: int) -> dict:
    import vcirun

    betas = np.random.default_rng(30).uniform(3.2, 5.2, k)
    sample = betas[: min(k, 400)]
    vcirun.ensemble("cart_pendulum", "CVA", h=1e-2, T=5, beta=sample[:4])
    loops = [vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5, beta=float(b)).wall_time for b in sample]
    t = time.perf_counter()
    cpu = time.process_time()
    ds = vcirun.ensemble("cart_pendulum", "CVA", h=1e-2, T=5, beta=betas)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    loops += [vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5, beta=float(b)).wall_time for b in sample]
    loop = statistics.median(loops)
    loop_cpu = _loop_cpu(sample)
    cores = _cores()
    ok = int((ds.status == "ok").sum())
    return {"k": k, "wall_s": wall, "cpu_s": cpu, "loop_ms": loop * 1e3, "loop_cpu_ms": loop_cpu * 1e3,
            "cores": cores, "ok": ok, "ratio": wall / (k * loop / cores), "parallelism": cpu / wall,
            "cpu_ratio": cpu / (k * loop_cpu)}


def _loop_cpu(betas) -> float:
    """CPU seconds of the compiled loop alone per run (the same runs, called directly with reused
    buffers): the yardstick of the ensemble's CPU time, unaffected by other processes' load."""
    from vcirun.run import plan as P

    p = P.plan("cart_pendulum", "CVA", h=1e-2, T=5, start={"beta": float(betas[0])})
    mod = p.module()
    prm = p.sysd.param_values(None)
    starts = [P.ready_start(p, mod, P.start_state(p.sysd, float(b), None, None, prm, None), prm) for b in betas]
    buffers = P.Buffers(keep_grid=True)
    m = int(mod.NCON)
    out = buffers.get(p.N, p.sysd.n, m, 10 * p.N)
    info = np.zeros(6, dtype=np.int64)
    t = time.process_time()
    for q0, p0 in starts:
        mod.integrate(q0, p0, 0.0, p.h, p.N, prm, p.settings, out, info)
    return (time.process_time() - t) / len(starts)


_SWEEP = """
import json, resource, sys, time
from vcirun.experiments.config import load_config
from vcirun.experiments.sweep import run_sweep
cfg = load_config("configs/fig4.yaml")
t = time.perf_counter()
s = run_sweep(cfg, output=sys.argv[1], force=True, workers=int(sys.argv[2]), progress=False)
cpu = sum(getattr(resource.getrusage(w), f) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
          for f in ("ru_utime", "ru_stime"))
print(json.dumps({"wall": time.perf_counter() - t, "prepare": s.prepare_time, "write": s.write_time,
                  "computed": s.computed, "failed": s.failed, "cpu": cpu}))
"""


def _sweep_once(tree: Path, cache: Path, out: Path, workers: int) -> dict:
    env = dict(os.environ, VCIRUN_CACHE_DIR=str(cache), PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, "-c", _SWEEP, str(out), str(workers)], cwd=tree, env=env,
                       capture_output=True, text=True, timeout=3600)
    if r.returncode != 0:
        return {"error": (r.stderr.strip().splitlines() or ["?"])[-1]}
    d = json.loads(r.stdout.strip().splitlines()[-1])
    d["compute"] = d["wall"] - d["prepare"]
    return d


def _l2_equal(a: Path, b: Path) -> str:
    import vcirun

    la, lb = vcirun.open_results(a).l2_error.values, vcirun.open_results(b).l2_error.values
    if la.shape == lb.shape and np.array_equal(la, lb, equal_nan=True):
        return f"identical ({np.isfinite(la).sum()} errors)"
    return f"DIFFER (max rel {float(np.nanmax(np.abs(la - lb) / np.abs(lb))):.3g})"


def row_sweep(base: Path, rounds: int, base_cache: str | None = None) -> dict:
    """This tree with $VCIRUN_CACHE_DIR (else a fresh cache), BASE with `base_cache` (else a fresh one);
    one untimed sweep each first, so that both caches are warm."""
    workers = _cores()
    with tempfile.TemporaryDirectory(prefix="vcirun_tp_") as d:
        d = Path(d)
        trees = {"new": ROOT, "base": base}
        caches = {"new": Path(os.environ.get("VCIRUN_CACHE_DIR") or d / "cache_new"),
                  "base": Path(base_cache or d / "cache_base")}
        res = {name: [] for name in trees}
        for name, tree in trees.items():   # warm each cache (kernels compiled or loaded; not timed)
            _sweep_once(tree, caches[name], d / f"{name}.h5", workers)
        for r in range(rounds):
            order = list(trees) if r % 2 == 0 else list(trees)[::-1]
            for name in order:
                res[name].append(_sweep_once(trees[name], caches[name], d / f"{name}.h5", workers))
        errors = [x["error"] for v in res.values() for x in v if "error" in x]
        if errors:
            return {"error": errors[0]}
        med = {name: statistics.median(x["compute"] for x in v) for name, v in res.items()}
        cpu = {name: statistics.median(x["cpu"] for x in v) for name, v in res.items()}
        return {"workers": workers, "new_compute_s": med["new"], "base_compute_s": med["base"],
                "ratio": med["new"] / med["base"], "new_cpu_s": cpu["new"], "base_cpu_s": cpu["base"],
                "cpu_ratio": cpu["new"] / cpu["base"], "runs": res, "l2": _l2_equal(d / "new.h5", d / "base.h5")}


_FIRST = """
import json, time
t = time.perf_counter()
import vcirun
tr = vcirun.simulate("cart_pendulum", "CVA", h=1e-2, T=5, beta=3.2)
print(json.dumps({"s": time.perf_counter() - t, "status": tr.status}))
"""


def _first_once(tree: Path) -> dict:
    with tempfile.TemporaryDirectory(prefix="vcirun_first_") as d:
        env = dict(os.environ, VCIRUN_CACHE_DIR=d, PYTHONPATH=str(tree))
        t = time.perf_counter()
        r = subprocess.run([sys.executable, "-c", _FIRST], cwd=tree, env=env, capture_output=True, text=True,
                           timeout=3600)
        if r.returncode != 0:
            return {"error": (r.stderr.strip().splitlines() or ["?"])[-1]}
        out = json.loads(r.stdout.strip().splitlines()[-1])
        out["process_s"] = time.perf_counter() - t
        return out


def row_first(preshared: Path) -> dict:
    new, old = _first_once(ROOT), _first_once(preshared)
    if "error" in new or "error" in old:
        return {"error": new.get("error") or old.get("error")}
    return {"new_s": new["process_s"], "preshared_s": old["process_s"], "ratio": new["process_s"] / old["process_s"]}


def row_makerun() -> dict:
    """`make run` in a fresh clone of HEAD with an empty kernel cache (seconds; pip's cache as it is)."""
    with tempfile.TemporaryDirectory(prefix="vcirun_makerun_") as d:
        clone = Path(d) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        env = {k: v for k, v in os.environ.items()
               if k not in ("PYTHONPATH", "VIRTUAL_ENV", "VCIRUN_CACHE_DIR", "VCIRUN_TIER")}   # as a user runs it
        env["VCIRUN_CACHE_DIR"] = str(Path(d) / "cache")
        env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep) if ".venv" not in p)
        steps, t0 = {}, time.perf_counter()
        for name, target in (("install", "install"), ("run", "run")):
            t = time.perf_counter()
            r = subprocess.run(["make", target], cwd=clone, env=env, capture_output=True, text=True, timeout=3600)
            steps[name] = time.perf_counter() - t
            if r.returncode != 0:
                return {"error": f"make {target}: " + (r.stderr.strip().splitlines() or ["?"])[-1]}
        wall = time.perf_counter() - t0
        return {"wall_s": wall, "install_s": steps["install"], "sweep_and_plot_s": steps["run"], "ratio": wall}


def section_throughput(res, quick=False, k=None, base="/work/base", preshared="/work/preshared",
                       rows=("simulate", "ensemble", "sweep", "first", "makerun"), base_cache=None):
    log("== throughput: sweeps at the speed of the compiled loop (targets: `make bench`, this machine)")
    load0 = os.getloadavg()[0]
    out = {}
    if "simulate" in rows:
        out["simulate"] = row_simulate(101 if quick else 401)
    if "ensemble" in rows:
        out["ensemble"] = row_ensemble(k or (10_000 if quick else 100_000))
    if "sweep" in rows:
        out["sweep"] = row_sweep(Path(base), 1 if quick else 3, base_cache) if Path(base).is_dir() else \
            {"error": f"no tree at {base} (--base)"}
    if "first" in rows:
        out["first"] = row_first(Path(preshared)) if Path(preshared).is_dir() else \
            {"error": f"no tree at {preshared} (git worktree add {preshared} b6a8a5a)"}
    if "makerun" in rows:
        out["makerun"] = row_makerun()
    out["load_average"] = [load0, os.getloadavg()[0]]
    res["throughput"] = out
    log(f"  {'row':48s} {'measured':>64s} {'ratio':>7s} {'target':>7s}")
    lines = {
        "simulate": lambda r: ("simulate() / its loop, CVA cart-pendulum h=1e-2",
                               f"{r['call_ms']:.3f} ms call, {r['loop_ms']:.3f} ms loop"),
        "ensemble": lambda r: (f"ensemble of {r['k']} CVA runs / (k loop / {r['cores']} cores)",
                               f"{r['wall_s']:.2f} s, loop {r['loop_ms']:.3f} ms, CPU/wall {r['parallelism']:.2f}, "
                               f"CPU / (k loop CPU) {r['cpu_ratio']:.2f}"),
        "sweep": lambda r: ("fig4 sweep compute / today's tree",
                            f"{r['new_compute_s']:.2f} s vs {r['base_compute_s']:.2f} s (CPU {r['new_cpu_s']:.1f} s vs "
                            f"{r['base_cpu_s']:.1f} s: x{r['cpu_ratio']:.2f}); L2 {r['l2']}"),
        "first": lambda r: ("first simulate CVA, empty cache / pre-shared tree",
                            f"{r['new_s']:.1f} s vs {r['preshared_s']:.1f} s"),
        "makerun": lambda r: ("`make run` in a fresh clone, s (target: seconds)",
                              f"install {r['install_s']:.1f} s + sweep and plot {r['sweep_and_plot_s']:.1f} s"),
    }
    for name in rows:
        r = out[name]
        if "error" in r:
            log(f"  {name:40s} not measured: {r['error']}")
            continue
        label, text = lines[name](r)
        mark = "ok" if r["ratio"] <= TARGETS[name] else "MISSED"
        log(f"  {label:48s} {text:>64s} {r['ratio']:7.2f} {TARGETS[name]:7.2f} {mark}")
    log(f"  load average {out['load_average'][0]:.2f} at start, {out['load_average'][1]:.2f} at end")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--k", type=int, default=None)
    ap.add_argument("--base", default="/work/base")
    ap.add_argument("--preshared", default="/work/preshared")
    ap.add_argument("--rows", default="simulate,ensemble,sweep,first,makerun")
    ap.add_argument("--base-cache", default=os.environ.get("VCIRUN_BENCH_BASE_CACHE"),
                    help="VCIRUN_CACHE_DIR of the base tree (default: a fresh one, compiled by the warm-up)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    res = {}
    section_throughput(res, quick=a.quick, k=a.k, base=a.base, preshared=a.preshared, rows=tuple(a.rows.split(",")),
                       base_cache=a.base_cache)
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(res, indent=1, default=float))


if __name__ == "__main__":
    main()
