"""Contacts by the hundred: cold build, cost per smooth step and the first-hit outcome of a cradle of
N balls (newton_cradle_N: a line of free balls, e = 1, balls 2..N touching, ball 1 arriving at speed
1) and of an N-link chain falling on a floor (link_chain_N, declared by bodies), one case per fresh
process (`make bench` section "bodies"; printed, never asserted).

    python bench/bodies_scaling.py [--cases newton_cradle_3,newton_cradle_10,link_chain_5] [--method CVA]
                                   [--timeout 3600] [--out results/bodies_scaling.json]

Per case: cold build = wall of the first vcirun.simulate of the scene (its kernels are new; the
method's shared core may be cached, as after any earlier scene); us per smooth step = CPU time of a
run before the first impact divided by its steps (h = 1e-4); first hit (cradles): the velocities
after the first impact against NNLS on the LCP written from the equations (W = G M^-1 G^T of the
N - 1 touching contacts, u- = (-1, 0, ..., 0)), and against the closed form (1.4) of docs/derivations/contacts.md.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = ("newton_cradle_3,newton_cradle_10,newton_cradle_30,newton_cradle_100,"
           "link_chain_3,link_chain_5,link_chain_10")


def one(case: str, method: str) -> dict:
    import numpy as np

    t0 = time.perf_counter()
    import vcirun
    from vcirun.scenes.registry import scene_data

    t_import = time.perf_counter() - t0
    d = scene_data(case)
    t1 = time.perf_counter()
    vcirun.simulate(case, method, h=1e-3, T=2e-3)
    cold = time.perf_counter() - t1
    out = {"case": case, "method": method, "n": d.n, "import_s": t_import, "cold_build_s": cold}
    T = 0.19 if case.startswith("newton_cradle") else 0.25   # before the first impact (0.2 s; chain ~0.29 s)
    h = 1e-4
    # CPU of this thread: process time would count BLAS threads that spin after the previous case's
    # NNLS (measured: 25-50 us per step on the second and third run of a process against 14-29 on the first)
    c0 = time.thread_time()
    tr = vcirun.simulate(case, method, h=h, T=T, energies=False)
    cpu = time.thread_time() - c0
    out |= {"smooth_steps": len(tr.t) - 1, "impacts_in_smooth_run": len(tr.impacts),
            "us_per_smooth_step": cpu / (len(tr.t) - 1) * 1e6, "status_smooth": tr.status}
    if case.startswith("newton_cradle"):
        N = d.n
        tr = vcirun.simulate(case, method, h=1e-3, T=0.3)
        m = d.params["m"]
        v = tr.p[-1] / m
        from scipy.optimize import nnls

        G = np.zeros((N - 1, N))
        for i in range(N - 1):
            G[i, i], G[i, i + 1] = -1.0, 1.0
        W = G @ G.T / m
        um = np.zeros(N - 1)
        um[0] = -1.0
        C = np.linalg.cholesky(W)
        lam, _ = nnls(C.T, -np.linalg.solve(C, 2.0 * um), maxiter=100 * N)
        vref = np.zeros(N)
        vref[0] = 1.0
        vref += G.T @ lam / m
        closed = np.full(N, 2.0 / N)
        closed[0] = (1.0 - (N - 1)) / N
        out |= {"status_hit": tr.status, "message_hit": tr.message[:300], "impacts_hit": len(tr.impacts),
                "first_hit_vs_nnls": float(np.max(np.abs(v - vref))),
                "first_hit_vs_closed_form": float(np.max(np.abs(v - closed)))}
    else:
        tr = vcirun.simulate(case, method, h=1e-3, T=0.45)
        out |= {"status_hit": tr.status, "impacts_hit": len(tr.impacts), "message_hit": tr.message[:300]}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=DEFAULT)
    ap.add_argument("--method", default="CVA")
    ap.add_argument("--timeout", type=float, default=3600)
    ap.add_argument("--out", default=None)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        print(json.dumps(one(a.one, a.method)))
        return
    rows = []
    print(f"== bodies: cold build and us per smooth step ({a.method}; fresh process per case)", flush=True)
    for case in a.cases.split(","):
        t0 = time.perf_counter()
        try:
            r = subprocess.run([sys.executable, __file__, "--one", case, "--method", a.method], capture_output=True,
                               text=True, timeout=a.timeout, cwd=ROOT, env=dict(os.environ))
            row = (json.loads(r.stdout.strip().splitlines()[-1]) if r.returncode == 0 else
                   {"case": case, "error": (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]})
        except subprocess.TimeoutExpired:
            row = {"case": case, "error": f"timed out after {a.timeout:.0f} s"}
        row["process_wall_s"] = time.perf_counter() - t0
        try:
            row["loadavg"] = os.getloadavg()[0]
        except OSError:
            pass
        rows.append(row)
        if "error" in row:
            print(f"  {case:20s} {row['error']}", flush=True)
            continue
        hit = (f"first hit vs NNLS {row['first_hit_vs_nnls']:.2e}, vs (1.4) {row['first_hit_vs_closed_form']:.2e}"
               if "first_hit_vs_nnls" in row else f"{row['impacts_hit']} impacts by t = 0.45 ({row['status_hit']})")
        print(f"  {case:20s} n = {row['n']:3d}  cold build {row['cold_build_s']:7.1f} s   "
              f"{row['us_per_smooth_step']:9.2f} us/smooth step   {hit}   (load {row.get('loadavg', 0):.1f})",
              flush=True)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
