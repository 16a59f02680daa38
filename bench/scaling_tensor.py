"""Scaling: step kernels from per-slot tensors (vcirun.codegen.tensor) vs the expanded
slot expressions (vcirun.discrete.lagrangians.step_expressions), for CVA (SVC) on the n-link
pendulum (n = K = 1, 2, 4, 8) and the cart-pendulum.

Per (scene, kernel path), in fresh processes (bench/_probe.py, as bench_all.py) and a fresh kernel
cache directory, so every build is cold (symbolic work + numba compile, nothing on disk):
  symbolic_s    module generation on the cache miss (sympy + source assembly, the build report)
  numba_s       first 10-step simulation minus symbolic_s (numba compile of the whole module)
  source_chars  size of the generated module
  us_per_step   CPU microseconds per smooth step (constraint ignored, h = 1e-3, 20000 steps, median
                of 5) in a second, warm process
The kernel path is selected with VCIRUN_KERNEL_PATH=tensor|expanded (vcirun.codegen.derive). The
exponents are least-squares slopes of log(quantity) against log(n) over the n-link pendulum rows.

With --mcvac, also the symbolic split of MCVAC's module (in this process, no numba): system + step
kernels (tensor path) against the modified-Hamiltonian kernels (vcirun.codegen.mh_kernels, not changed
by the tensor path; their own scaling: bench/scaling_mh.py), with their source sizes.

    python bench/scaling_tensor.py [--quick] [--mcvac] [--output=PATH]
                                   (JSON to results/scaling_tensor.json)
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PATHS = ("tensor", "expanded")


def fit_exponent(x, y) -> float:
    x, y = np.asarray(x, float), np.asarray(y, float)
    m = np.isfinite(x) & np.isfinite(y) & (x > 0) & (y > 0)
    if m.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(x[m]), np.log(y[m]), 1)[0])


def probe(args: dict, cache_dir, kernel_path: str, timeout=2400) -> dict:
    env = dict(os.environ, VCIRUN_CACHE_DIR=str(cache_dir), VCIRUN_KERNEL_PATH=kernel_path)
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, str(ROOT / "bench" / "_probe.py"), json.dumps(args)], env=env,
                           capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"error": f"timed out after {timeout} s"}
    if r.returncode != 0:
        return {"error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}"}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    out["process_wall_s"] = time.perf_counter() - t0
    return out


def measure(system: str, kernel_path: str) -> dict:
    row = {"system": system, "kernel_path": kernel_path}
    a = {"mode": "build", "system": system, "method": "CVA", "h": 1e-3, "T": 0.01}
    if system == "cart_pendulum":
        a["beta"] = 3.2
    with tempfile.TemporaryDirectory(prefix="vcirun_scaling_") as d:
        cold = probe(a, d, kernel_path)
        warm = probe(a | {"measure_steps": 20000, "measure_h": 1e-3}, d, kernel_path) if "error" not in cold else {}
    with tempfile.TemporaryDirectory(prefix="vcirun_scaling_") as d:
        src = probe({"mode": "derive", "system": system, "method": "CVA"}, d, kernel_path)
    for part in (cold, warm, src):
        if "error" in part:
            row["error"] = part["error"]
            return row
    if cold.get("cached"):
        row["error"] = "cold build found a cached module"
        return row
    row.update(symbolic_s=cold["generate_s"], numba_s=cold["first_sim_s"] - cold["generate_s"],
               source_chars=src["source_chars"], derive_s=src["derive_s"], us_per_step=warm["us_per_step"],
               newton_iters=warm["measure_newton_iters"], us_per_step_all=warm["us_per_step_all"])
    return row


def mcvac_symbolic(Ks) -> list:
    from vcirun.codegen import derive
    from vcirun.scenes.registry import get_scene
    from vcirun.methods.table import resolve_method
    from vcirun.codegen.mh_kernels import modified_kernels_source

    rows = []
    for K in Ks:
        s = get_scene(f"n_pendulum_{K}")
        ks = resolve_method("MCVAC").kernel_set()
        t0 = time.process_time()
        a = derive.system_kernels_source(s, "tensor") + derive.ld_kernels_source(
            s, list(ks.explicit_names), ks.part("energy_gradient"), "tensor")
        t1 = time.process_time()
        b = modified_kernels_source(s, ks)
        t2 = time.process_time()
        rows.append({"K": K, "step_system_symbolic_s": t1 - t0, "step_system_chars": len(a),
                     "modified_symbolic_s": t2 - t1, "modified_chars": len(b)})
        print(f"n_pendulum_{K} MCVAC: system + step kernels {t1 - t0:.2f} s ({len(a) / 1e3:.0f} kB), "
              f"modified-Hamiltonian kernels {t2 - t1:.2f} s ({len(b) / 1e3:.0f} kB)", flush=True)
    return rows


def main(argv):
    out = ROOT / "results" / "scaling_tensor.json"
    quick = "--quick" in argv
    for a in argv:
        if a.startswith("--output="):
            out = Path(a.split("=", 1)[1])
    Ks = [1, 2, 4] if quick else [1, 2, 4, 8]
    systems = ["cart_pendulum"] + [f"n_pendulum_{K}" for K in Ks]
    rows = []
    for s in systems:
        for p in PATHS:
            r = measure(s, p)
            rows.append(r)
            if "error" in r:
                print(f"{s:15s} {p:8s}: {r['error']}", flush=True)
            else:
                print(f"{s:15s} {p:8s}: symbolic {r['symbolic_s']:7.3f} s  numba {r['numba_s']:6.2f} s  "
                      f"source {r['source_chars'] / 1e3:7.1f} kB  {r['us_per_step']:7.3f} us/step "
                      f"({r['newton_iters']:.2f} Newton it.)", flush=True)
    exps = {}
    for p in PATHS:
        ok = [r for r in rows if r["kernel_path"] == p and r["system"].startswith("n_pendulum_") and "error" not in r]
        n = [int(r["system"].rsplit("_", 1)[1]) for r in ok]
        exps[p] = {k: fit_exponent(n, [r[k] for r in ok]) for k in ("symbolic_s", "numba_s", "source_chars", "us_per_step")}
        print(f"exponents in n ({p}): " + ", ".join(f"{k} {v:.2f}" for k, v in exps[p].items()))
    res = {"method": "CVA (SVC), smooth steps h = 1e-3", "rows": rows, "exponents": exps,
           "cpu_count": os.cpu_count(), "load_avg_at_end": os.getloadavg()}
    if "--mcvac" in argv:
        m = mcvac_symbolic(Ks)
        res["mcvac_symbolic"] = {"rows": m, "exponents": {
            k: fit_exponent([r["K"] for r in m], [r[k] for r in m])
            for k in ("modified_symbolic_s", "modified_chars", "step_system_symbolic_s")}}
        print("exponents in n (MCVAC symbolic): " + ", ".join(
            f"{k} {v:.2f}" for k, v in res["mcvac_symbolic"]["exponents"].items()))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    print(f"saved {out}")
    return res


if __name__ == "__main__":
    main(sys.argv[1:])
