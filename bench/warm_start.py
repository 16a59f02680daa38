"""Warm start: a process whose kernel module is cached, timed from outside and inside.

    .venv/bin/python bench/warm_start.py [--repeats 7] [--cache-dir DIR] [--out results/warm_start.json]

Fresh processes, interleaved per repeat (so machine-load drift hits every variant alike):
  python  `python -c pass` (interpreter start and exit)
  api     `import vcirun; vcirun.simulate('cart_pendulum', 'CVA', h=1e-2, T=5, beta=3.2)`: whole-process
          wall; inside: `import vcirun` time and time to the first finished simulation; whether sympy,
          scipy.integrate were imported; whether the module came from the warm index
  yaml    the same for the cart-pendulum declared as a YAML system file
  cli     `vcirun simulate --system cart_pendulum --method CVA --h 0.01 --T 5 --beta 3.2`
  floor   numpy + numba + the cached kernel module loaded by path + one simulation (what any warm
          start must do; no vcirun import)
Each variant runs twice: as the environment is configured (here PYTHONDONTWRITEBYTECODE=1 and no
__pycache__ in the source tree, so vcirun's own modules are compiled from source in every process)
and with a bytecode cache (PYTHONPYCACHEPREFIX in a temporary directory, as an installed package
has). Medians (and min, max) over the repeats; JSON to --out.

By default the processes run a snapshot of the vcirun package (copied to a temporary directory,
first on PYTHONPATH): the kernel cache key hashes vcirun's source files, and an edit in the working
tree during the benchmark would otherwise turn warm runs into cold builds. --no-snapshot runs the
working tree.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PY = sys.executable
CLI = str(Path(PY).with_name("vcirun"))

CART_YAML = """name: cart_pendulum_yaml
coordinates: [y, theta]
parameters: {m1: 1.0, m2: 0.2, L: 2.0, g: 10.0}
mass_matrix:
  - ["m1 + m2", "m2*L*sin(theta)"]
  - ["m2*L*sin(theta)", "m2*L**2"]
potential: "(m1 + m2)*g*y - m2*g*L*cos(theta)"
constraint: "y"
"""

API = r"""
import time
T0 = time.perf_counter()
import sys, json
import vcirun
t_imp = time.perf_counter() - T0
kw = dict(h=1e-2, T=5.0)
kw.update(json.loads(sys.argv[2]))
from vcirun.codegen.kernel_cache import default
with default().report() as built:
    tr = vcirun.simulate(sys.argv[1], "CVA", **kw)
t_sim = time.perf_counter() - T0
BUILD_LOG = built.entries
print(json.dumps({"import_s": t_imp, "to_first_sim_s": t_sim, "status": tr.status,
                  "impacts": len(tr.impacts), "sympy": "sympy" in sys.modules,
                  "scipy_integrate": "scipy.integrate" in sys.modules, "scipy": "scipy" in sys.modules,
                  "cached": all(b["cached"] for b in BUILD_LOG), "warm_index": all(b.get("warm_index") for b in BUILD_LOG),
                  "module_key": BUILD_LOG[-1]["key"]}))
"""

FLOOR = r"""
import time
T0 = time.perf_counter()
import importlib.util, json, sys
import numpy as np
import numba
path, name = sys.argv[1], sys.argv[2]
spec = importlib.util.spec_from_file_location(name, path)
mod = importlib.util.module_from_spec(spec)
sys.modules[name] = mod
spec.loader.exec_module(mod)
N, n, cap = 500, 2, 141
q0 = np.array([3.2, 0.0])
prm = np.array([1.0, 0.2, 2.0, 10.0])
A = np.zeros((2, 2))
mod.sys_M(q0, prm, A)                         # the Legendre transform of Xi(3.2), as simulate does it
p0 = A @ np.array([0.0, 3.5 - 0.18 * 3.2])
out = [np.zeros((N + 1, n)), np.zeros((N + 1, n)), np.zeros(N + 1), np.zeros(N + 1), np.zeros(N + 1), np.zeros(cap),
       np.zeros((cap, n)), np.zeros((cap, n)), np.zeros((cap, n)), np.zeros(N, np.bool_), np.zeros(2 * cap + 16),
       np.zeros(N, np.int64), np.zeros(5, np.int64)]
mod.integrate(q0, p0, 0.0, 1e-2, N, prm, True, 1e-12, 50, 1e-13, 64, *out, True)  # simulate's signature
print(json.dumps({"to_first_sim_s": time.perf_counter() - T0, "impacts": int(out[-1][2]),
                  "sympy": "sympy" in sys.modules, "scipy": "scipy" in sys.modules}))
"""


def run(cmd, env) -> tuple[float, dict]:
    t0 = time.perf_counter()
    # not cwd=ROOT: `python -c` puts the working directory first on sys.path, ahead of the snapshot
    r = subprocess.run(cmd, env=env, cwd=env.get("VCIRUN_BENCH_CWD", ROOT), capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{cmd[:3]} failed ({r.returncode}): {r.stderr[-2000:]}")
    info = {}
    last = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
    if last.startswith("{"):
        info = json.loads(last)
    return wall, info


def stats(xs):
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "all": xs}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--cache-dir", default=None, help="VCIRUN_CACHE_DIR (default: a fresh temporary directory)")
    ap.add_argument("--out", default=str(ROOT / "results" / "warm_start.json"))
    ap.add_argument("--no-snapshot", action="store_true", help="run the working tree, not a copy of vcirun/")
    a = ap.parse_args()
    tmp = tempfile.TemporaryDirectory(prefix="vcirun_warm_")
    cache = a.cache_dir or str(Path(tmp.name) / "cache")
    yaml_path = Path(tmp.name) / "cart.yaml"
    yaml_path.write_text(CART_YAML)
    base = {k: v for k, v in os.environ.items()} | {"VCIRUN_CACHE_DIR": cache}
    if not a.no_snapshot:
        src = Path(tmp.name) / "src"
        shutil.copytree(ROOT / "vcirun", src / "vcirun", ignore=shutil.ignore_patterns("__pycache__"))
        base["PYTHONPATH"] = os.pathsep.join([str(src)] + ([base["PYTHONPATH"]] if base.get("PYTHONPATH") else []))
        base["VCIRUN_BENCH_CWD"] = tmp.name
    envs = {"as configured": base,
            "bytecode cache": {k: v for k, v in base.items() if k != "PYTHONDONTWRITEBYTECODE"}
            | {"PYTHONPYCACHEPREFIX": str(Path(tmp.name) / "pyc")}}
    beta = json.dumps({"beta": 3.2})
    variants = {
        "python": lambda: [PY, "-c", "pass"],
        "api": lambda: [PY, "-c", API, "cart_pendulum", beta],
        "yaml": lambda: [PY, "-c", API, str(yaml_path), json.dumps({"q0": [0.3, 0.2], "p0": [0.0, 0.8]})],
        "cli": lambda: [CLI, "simulate", "--system", "cart_pendulum", "--method", "CVA", "--h", "0.01", "--T", "5",
                        "--beta", "3.2"],
    }
    # prepare: build (cold) and index every module, fill both bytecode caches
    print(f"cache {cache}; preparing (a cold build compiles for a while) ...", flush=True)
    for env in envs.values():
        for _ in range(2):
            _, info = run(variants["api"](), env)
            run(variants["yaml"](), env)
            run(variants["cli"](), env)
    key = info["module_key"]
    pkg = subprocess.run([PY, "-c", "import vcirun; print(vcirun.__file__)"], env=base, capture_output=True, text=True,
                         cwd=base.get("VCIRUN_BENCH_CWD", ROOT)).stdout.strip()
    print(f"vcirun imported from {pkg}", flush=True)
    mod_path = str(Path(cache) / "kernels" / f"vk_{key}.py")
    variants["floor"] = lambda: [PY, "-c", FLOOR, mod_path, f"vcirun_kernels_{key}"]
    run(variants["floor"](), base)

    res = {e: {v: {"wall": [], "info": []} for v in variants} for e in envs}
    for i in range(a.repeats):
        for e, env in envs.items():
            for v, cmd in variants.items():
                wall, info = run(cmd(), env)
                res[e][v]["wall"].append(wall)
                res[e][v]["info"].append(info)
        print(f"  repeat {i + 1}/{a.repeats} done", flush=True)

    summary = {}
    for e in envs:
        summary[e] = {}
        for v in variants:
            r = res[e][v]
            s = {"process_wall_s": stats(r["wall"])}
            if r["info"] and "to_first_sim_s" in r["info"][0]:
                s["to_first_sim_s"] = stats([x["to_first_sim_s"] for x in r["info"]])
            if r["info"] and "import_s" in r["info"][0]:
                s["import_s"] = stats([x["import_s"] for x in r["info"]])
                for flag in ("sympy", "scipy_integrate", "scipy", "cached", "warm_index"):
                    s[flag] = sorted({x[flag] for x in r["info"]})
            elif r["info"] and "sympy" in r["info"][0]:
                for flag in ("sympy", "scipy"):
                    s[flag] = sorted({x[flag] for x in r["info"]})
            summary[e][v] = s

    def med(s, k):
        return f"{s[k]['median']:.3f}" if k in s else "-"

    print(f"\nwarm start, medians over {a.repeats} fresh processes (s); load average "
          f"{os.getloadavg()[0]:.2f} at the end")
    print(f"{'environment':16s} {'variant':7s} {'process wall':>12s} {'(min)':>7s} {'import vcirun':>13s} "
          f"{'first sim done':>14s}  imported")
    for e in envs:
        for v in variants:
            s = summary[e][v]
            flags = ", ".join(f"{f}={s[f]}" for f in ("sympy", "scipy_integrate", "scipy", "warm_index") if f in s)
            print(f"{e:16s} {v:7s} {s['process_wall_s']['median']:12.3f} {s['process_wall_s']['min']:7.3f} "
                  f"{med(s, 'import_s'):>13s} {med(s, 'to_first_sim_s'):>14s}  {flags}")
    out = {"repeats": a.repeats, "cache_dir": cache, "snapshot": not a.no_snapshot, "vcirun_file": pkg, "module_key": key, "loadavg_end": os.getloadavg(),
           "summary": summary, "raw": res}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print(f"wrote {a.out}")
    tmp.cleanup()


if __name__ == "__main__":
    main()
