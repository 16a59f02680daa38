"""Prototype: derive per-slot tensors instead of expanded slot expressions.

Today (vcirun.codegen.derive) every step kernel is the *expanded* symbolic expression of the slot
derivatives of Ld^SVC in (q0, v, h): Pm = -D1 Ld, its Jacobian dPm/dv, Pp = D2 Ld, Ed = -D3 Ld.
Each entry mixes M(q0), M(q0 + h v), their derivatives and V, and CSE has to rediscover the shared
pieces in n^2 Jacobian entries of growing size.

For L = 1/2 v^T M(q) v - V(q) the slot derivatives of SVC are small contractions of three tensors,
   M(q) (n x n),   dM(q)[i, j, k] = dM_ij / dq_k (n x n x n),   dV(q) (n),
evaluated at q0 and q1 = q0 + h v:
   A    = (M(q0) + M(q1)) / 2
   gL(q, v)_k = 1/2 v^T dM_k(q) v - dV_k(q)
   Pm   = A v - h/2 gL(q0, v)                     (= -D1 Ld)
   Pp   = A v + h/2 gL(q1, v)                     (=  D2 Ld)
   dPm/dv = A + h/2 [dM(q1) v]_{i,k} (from q1 = q0 + h v) - h/2 [dM(q0) v]^T_{i,k}   (exact)
   Ed   = -D3 Ld = 1/2 v^T A v + (V(q0) + V(q1))/2 - h/2 * 1/2 v^T (dM(q1) v) v + h/2 dV(q1) . v
So the symbolic work is: M, its n^3 first derivatives, V and dV -- each a derivative of one small
entry, CSE'd once in ONE kernel -- and the contractions are a few numba loops (O(n^3) flops).

This file measures, for the n-link pendulum against a wall (n = 1, 2, 4, 8): the symbolic time of
the tensor kernel, its numba compile time, and microseconds per SVC step (same Newton iteration
and tolerance as vcirun's `explicit_step`), beside vcirun's generated CVA module; and it checks
the tensor step against vcirun's SVC step (same q1, p1 to round-off) before timing.

It also tries a cheaper Newton start (linear extrapolation of the last two step velocities).

    python bench/tensor_prototype.py [--output=PATH] [cart_pendulum] [K ...]
                                     (prints a table; JSON to results/tensor_prototype.json)
"""
from __future__ import annotations

import importlib.util
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

_STEP_SRC = '''
@njit(cache=True, nogil=True, error_model="numpy")
def _gl(dM, dV, v, out):
    # out_k = 1/2 v^T dM_k v - dV_k ; dM[i*n + j, k] = dM_ij/dq_k
    for k in range(NDOF):
        s = 0.0
        for i in range(NDOF):
            vi = v[i]
            for j in range(NDOF):
                s += vi * dM[i * NDOF + j, k] * v[j]
        out[k] = 0.5 * s - dV[k]


@njit(cache=True, nogil=True, error_model="numpy")
def tensor_svc_step(q0, p0, h, prm, ntol, maxit, q1, p1, W, guess=0):
    """SVC step from tensors: W is a work buffer (no allocation in the loop). guess 0: Newton starts at
    v = M(q0)^-1 p0 (as vcirun); guess 1: at the value already in W's v slot (the caller's guess)."""
    n = NDOF
    M0 = W[0:n * n].reshape((n, n))
    M1 = W[n * n:2 * n * n].reshape((n, n))
    J = W[2 * n * n:3 * n * n].reshape((n, n))
    dM0 = W[3 * n * n:3 * n * n + n * n * n].reshape((n * n, n))
    dM1 = W[3 * n * n + n * n * n:3 * n * n + 2 * n * n * n].reshape((n * n, n))
    off = 3 * n * n + 2 * n * n * n
    dV0 = W[off:off + n]
    dV1 = W[off + n:off + 2 * n]
    v = W[off + 2 * n:off + 3 * n]
    r = W[off + 3 * n:off + 4 * n]
    g0 = W[off + 4 * n:off + 5 * n]
    tsm_MdMdV(q0, prm, M0, dM0, dV0)
    if guess == 0:  # v = M0^-1 p0
        for i in range(n):
            v[i] = p0[i]
            for j in range(n):
                J[i, j] = M0[i, j]
        solve_small(J, v, n)
    _gl(dM0, dV0, v, g0)  # placeholder, recomputed in the loop
    it = 0
    ok = False
    while it < maxit:
        it += 1
        for i in range(n):
            q1[i] = q0[i] + h * v[i]
        tsm_MdMdV(q1, prm, M1, dM1, dV1)
        _gl(dM0, dV0, v, g0)
        for i in range(n):
            s = 0.0
            for j in range(n):
                a = 0.5 * (M0[i, j] + M1[i, j])
                s += a * v[j]
                # d/dv_k of (A v)_i through q1 and of -h/2 gL(q0, v)_i
                c1 = 0.0
                c0 = 0.0
                for l in range(n):
                    c1 += dM1[i * n + l, j] * v[l]      # sum_l dM_il(q1)/dq_j v_l
                    c0 += dM0[l * n + j, i] * v[l]      # sum_l dM_lj(q0)/dq_i v_l
                J[i, j] = a + 0.5 * h * c1 - 0.5 * h * c0
            r[i] = s - 0.5 * h * g0[i] - p0[i]
        if not solve_small(J, r, n):
            break
        dn = 0.0
        vn = 0.0
        for i in range(n):
            v[i] -= r[i]
            dn = max(dn, abs(r[i]))
            vn = max(vn, abs(v[i]))
        if dn <= ntol * (1.0 + vn):
            ok = True
            break
    for i in range(n):
        q1[i] = q0[i] + h * v[i]
    tsm_MdMdV(q1, prm, M1, dM1, dV1)
    _gl(dM1, dV1, v, g0)
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += 0.5 * (M0[i, j] + M1[i, j]) * v[j]
        p1[i] = s + 0.5 * h * g0[i]
    return it if ok else -it


@njit(cache=True, nogil=True, error_model="numpy")
def tensor_run(q0, p0, h, N, prm, ntol, maxit, W, guess=0):
    """N steps; guess 1: Newton starts at the linear extrapolation 2 v_{k-1} - v_{k-2} of the last two
    step velocities (O(h^2) from the root instead of O(h)), after two steps started at M^-1 p."""
    n = NDOF
    off = 3 * n * n + 2 * n * n * n
    q = q0.copy()
    p = p0.copy()
    q1 = np.empty(n)
    p1 = np.empty(n)
    va = np.empty(n)
    vb = np.empty(n)
    tot = 0
    for k in range(N):
        g = 0
        if guess == 1 and k >= 2:
            for i in range(n):
                W[off + 2 * n + i] = 2.0 * vb[i] - va[i]
            g = 1
        it = tensor_svc_step(q, p, h, prm, ntol, maxit, q1, p1, W, g)
        if it < 0:
            return -1, q, p
        tot += it
        va[:] = vb
        for i in range(n):
            vb[i] = W[off + 2 * n + i]
        q[:] = q1
        p[:] = p1
    return tot, q, p
'''


def tensor_module(system, cache):
    """(module, symbolic seconds, numba seconds incl. first call): the tensor kernel + the step."""
    import sympy as sp

    from vcirun.codegen.kernels import Kernel

    t0 = time.perf_counter()
    n = system.n
    q = list(system.q)
    M = system.M
    dM = sp.Matrix(n * n, n, lambda a, k: sp.diff(M[a // n, a % n], q[k]))
    dV = sp.Matrix([sp.diff(system.V, s) for s in q])
    k = Kernel("tsm_MdMdV", [("q", q)], [("M", M), ("dM", dM), ("dV", dV)], list(system.param_symbols))
    src = "\n\n".join([
        "import math\nimport numpy as np\nfrom numba import njit\n", f"NDOF = {n}",
        (ROOT / "vcirun/maps/linalg.py").read_text(), k.emit(), _STEP_SRC])
    t_sym = time.perf_counter() - t0
    path = Path(cache) / f"tensor_{system.name}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(f"tensor_{system.name}", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    W = np.zeros(3 * n * n + 2 * n ** 3 + 5 * n)
    prm = system.param_values()
    q0, p0 = system.initial_state(beta=3.2) if system.name == "cart_pendulum" else system.initial_state()
    t1 = time.perf_counter()
    mod.tensor_run(q0, p0, 1e-3, 2, prm, 1e-12, 50, W)
    t_numba = time.perf_counter() - t1
    return mod, t_sym, t_numba, len(src)


def measure(K, cache):
    import vcirun
    from vcirun.codegen.build import load_module
    from vcirun.scenes.declarations import get_scene
    from vcirun.methods.table import METHODS

    s = get_scene(f"n_pendulum_{K}" if isinstance(K, int) else K)
    mod, t_sym, t_numba, chars = tensor_module(s, cache)
    n = s.n
    W = np.zeros(3 * n * n + 2 * n ** 3 + 5 * n)
    prm = s.param_values()
    q0, p0 = s.initial_state(beta=3.2) if s.name == "cart_pendulum" else s.initial_state()
    p0 = p0 + 0.3  # a moving state
    # correctness: one tensor step against vcirun's SVC step (the CVA module's full map)
    vm = load_module(s, METHODS["CVA"].kernel_set())
    h = 1e-2
    qa, pa, va = np.empty(n), np.empty(n), np.empty(n)
    vm.full(q0, p0, h, 0.0, prm, 1e-14, 50, qa, pa, va)
    qb, pb = np.empty(n), np.empty(n)
    mod.tensor_svc_step(q0, p0, h, prm, 1e-14, 50, qb, pb, W)
    err = float(max(np.max(np.abs(qa - qb)), np.max(np.abs(pa - pb))))
    # timing: N steps, CPU time, median of 5; vcirun's smooth SVC step beside (same scene, h, state)
    N = 20000
    ts = []
    for _ in range(5):
        c0 = time.thread_time()
        it, _, _ = mod.tensor_run(q0, p0, 1e-3, N, prm, 1e-12, 50, W)
        ts.append((time.thread_time() - c0) / N * 1e6)
    tg = []
    for _ in range(5):
        c0 = time.thread_time()
        itg, qg, pg = mod.tensor_run(q0, p0, 1e-3, N, prm, 1e-12, 50, W, 1)
        tg.append((time.thread_time() - c0) / N * 1e6)
    _, qr, pr = mod.tensor_run(q0, p0, 1e-3, N, prm, 1e-12, 50, W, 0)
    guess_diff = float(max(np.max(np.abs(qg - qr)), np.max(np.abs(pg - pr))))
    tv = []
    for _ in range(5):
        c0 = time.thread_time()
        tr = vcirun.simulate(s, "SVC", h=1e-3, T=N * 1e-3, q0=q0, p0=p0)
        tv.append((time.thread_time() - c0) / N * 1e6)
    # vcirun's full step alone (no H, Ed, phi per step): its `full` called from a compiled loop
    from numba import njit

    full = vm.full

    @njit
    def full_run(q0, p0, h, N, prm):
        q = q0.copy()
        p = p0.copy()
        q1 = np.empty(q0.shape[0])
        p1 = np.empty(q0.shape[0])
        v = np.empty(q0.shape[0])
        tot = 0
        for k in range(N):
            it, E = full(q, p, h, 0.0, prm, 1e-12, 50, q1, p1, v)
            tot += it
            q[:] = q1
            p[:] = p1
        return tot

    full_run(q0, p0, 1e-3, 2, prm)
    tf = []
    for _ in range(5):
        c0 = time.thread_time()
        itf = full_run(q0, p0, 1e-3, N, prm)
        tf.append((time.thread_time() - c0) / N * 1e6)
    return {"K": K, "tensor_extrapolated_guess_us_per_step": statistics.median(tg),
            "tensor_extrapolated_guess_newton_iters": itg / N, "extrapolated_guess_final_state_diff": guess_diff,
            "vcirun_full_only_us_per_step": statistics.median(tf), "vcirun_full_newton_iters": itf / N,
            "tensor_symbolic_s": t_sym, "tensor_numba_s": t_numba, "tensor_source_chars": chars,
            "tensor_us_per_step": statistics.median(ts), "tensor_newton_iters": it / N,
            "vcirun_svc_us_per_step": statistics.median(tv), "max_diff_vs_vcirun_step": err}


def main(argv):
    out = ROOT / "results" / "tensor_prototype.json"
    if argv and argv[0].startswith("--output="):
        out = Path(argv[0].split("=", 1)[1])
        argv = argv[1:]
    Ks = [int(a) if a.isdigit() else a for a in argv] or ["cart_pendulum", 1, 2, 4, 8]
    rows = []
    with tempfile.TemporaryDirectory(prefix="vcirun_tensor_") as d:
        for K in Ks:
            r = measure(K, d)
            rows.append(r)
            print(f"{K if isinstance(K, str) else f'n_pendulum_{K}'}: tensor kernel symbolic {r['tensor_symbolic_s']:.3f} s, numba {r['tensor_numba_s']:.2f} s, "
                  f"{r['tensor_us_per_step']:.3f} us/step ({r['tensor_newton_iters']:.2f} Newton it.) | vcirun full step "
                  f"{r['vcirun_full_only_us_per_step']:.3f} us ({r['vcirun_full_newton_iters']:.2f} it.), in its loop "
                  f"with H, Ed {r['vcirun_svc_us_per_step']:.3f} us/step | tensor + extrapolated Newton guess "
                  f"{r['tensor_extrapolated_guess_us_per_step']:.3f} us ({r['tensor_extrapolated_guess_newton_iters']:.2f} it.) | step agrees to {r['max_diff_vs_vcirun_step']:.1e}",
                  flush=True)
    out.write_text(json.dumps(rows, indent=1))
    print(f"saved {out}")
    return rows


if __name__ == "__main__":
    main(sys.argv[1:])
