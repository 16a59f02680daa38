"""Prototype: the units as ordinary numba modules that import each other, the scene's kernel table an
argument of the loop, against the shared core's process-global slot table (vcirun.codegen.shared).

    python bench/kernel_table_prototype.py [--cases cart_pendulum,link_chain_10] [--repeats 31]

The smooth part of the loop (the full map Phi_h of explicit Lds, its Newton solve, the record of
q, p and the iterations, the finite check) is written twice as a package of ordinary modules
(written to a temporary directory, importing each other by name, no text assembly):

  argument  every function takes the scene record `sc` (a numba namedtuple: sizes, stage data,
            kernel addresses), kernels are called as kcall(sc.k_pmjc[sid], ...);
  global    the same functions read sizes and addresses from the slot table (slot(k)), as the shared
            core does.

Both call the scene's compiled kernels by address (the scene's `_p_` wrappers of the shared build,
taken from a module vcirun loaded). Printed per case (CVA's full map SVC and MCVAA's SVA = SE1 + SE2,
T = 5 from the scene's start, the constraint ignored): ms per run of each package and of the
shared core's own `integrate` with constrained = 0, energies = 0 (the same work); and, in fresh
processes with an empty numba cache, the cold compile of each package's loop and its warm load.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

LINALG = '''
import math
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def solve_band(A, b, n, bw):
    for k in range(n):
        rows = min(n, k + bw + 1)
        cols = min(n, k + 2 * bw + 1)
        piv = k
        amax = abs(A[k, k])
        for i in range(k + 1, rows):
            if abs(A[i, k]) > amax:
                amax = abs(A[i, k])
                piv = i
        if not amax > 0.0 or not math.isfinite(amax):
            return False
        if piv != k:
            for j in range(k, cols):
                tmp = A[k, j]
                A[k, j] = A[piv, j]
                A[piv, j] = tmp
            tmp = b[k]
            b[k] = b[piv]
            b[piv] = tmp
        inv = 1.0 / A[k, k]
        for i in range(k + 1, rows):
            f = A[i, k] * inv
            if f != 0.0:
                for j in range(k + 1, cols):
                    A[i, j] -= f * A[k, j]
                b[i] -= f * b[k]
    for k in range(n - 1, -1, -1):
        s = b[k]
        for j in range(k + 1, min(n, k + 2 * bw + 1)):
            s -= A[k, j] * b[j]
        b[k] = s / A[k, k]
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def copy_into(dst, src):
    for i in range(src.shape[0]):
        dst[i] = src[i]
'''

# The scene record and the kernel stubs (argument form). The global form is derived from this text.
TABLE = '''
from collections import namedtuple
from numba import njit
from vcirun.codegen.kcall import kcall

Scene = namedtuple("Scene", ("ndof", "node_len", "band", "stages", "fracs", "k_node", "k_node_M", "k_pmjc", "k_ppc"))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def sys_node(sc, q, prm, c):
    return kcall(sc.k_node, 0, "aaa", (q, prm, c))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def sys_node_M(sc, c, A):
    return kcall(sc.k_node_M, 0, "ab", (c, A))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def ld_PmJc(sc, sid, q0, v, h, t, prm, c, r, J):
    return kcall(sc.k_pmjc[sid], 0, "aaffaaab", (q0, v, h, t, prm, c, r, J))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def ld_Ppc(sc, sid, q0, v, h, t, prm, c, out, cn):
    return kcall(sc.k_ppc[sid], 0, "aaffaaaa", (q0, v, h, t, prm, c, out, cn))
'''

STEPS = '''
import math
import numpy as np
from numba import njit
from vcirun.codegen.frame import scratch, scratch2
from PKG.linalg import solve_band, copy_into
from PKG.table import sys_node, sys_node_M, ld_PmJc, ld_Ppc


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def explicit_step(sc, sid, q0, p0, h, t, prm, ntol, maxit, v, q1, p1, c, cn, r, J):
    it = 0
    converged = False
    dprev = np.inf
    while it < maxit:
        it += 1
        ld_PmJc(sc, sid, q0, v, h, t, prm, c, r, J)
        for i in range(sc.ndof):
            r[i] -= p0[i]
        if not solve_band(J, r, sc.ndof, sc.band):
            break
        dn = 0.0
        vn = 0.0
        for i in range(sc.ndof):
            v[i] -= r[i]
            dn = max(dn, abs(r[i]))
            vn = max(vn, abs(v[i]))
        if not math.isfinite(dn):
            break
        if dn <= ntol * (1.0 + vn):
            converged = True
            break
        theta = dn / dprev
        if it >= 2 and theta < 0.1 and theta / (1.0 - theta) * dn <= ntol * (1.0 + vn):
            converged = True
            break
        if it >= 3 and dn >= dprev and dn <= math.sqrt(ntol) * (1.0 + vn):
            converged = True
            break
        dprev = dn
    for i in range(sc.ndof):
        q1[i] = q0[i] + h * v[i]
    ld_Ppc(sc, sid, q0, v, h, t, prm, c, p1, cn)
    return it if converged else -it


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def guess_from_node(sc, c, p, v, A):
    sys_node_M(sc, c, A)
    for i in range(sc.ndof):
        v[i] = p[i]
    if not solve_band(A, v, sc.ndof, sc.band):
        for i in range(sc.ndof):
            v[i] = 0.0


@njit(cache=True, nogil=True, error_model="numpy")
def ld_step(sc, q0, p0, h, t, prm, ntol, maxit, q1, p1, vlast):
    v = scratch(sc.ndof)
    c = scratch(sc.node_len)
    cn = scratch(sc.node_len)
    r = scratch(sc.ndof)
    J = scratch2(sc.ndof, sc.ndof)
    sys_node(sc, q0, prm, c)
    guess_from_node(sc, c, p0, v, J)
    if sc.stages.shape[0] == 1:
        it = explicit_step(sc, sc.stages[0], q0, p0, h, t, prm, ntol, maxit, v, q1, p1, c, cn, r, J)
        copy_into(vlast, v)
        return it
    qa = scratch(sc.ndof)
    pa = scratch(sc.ndof)
    copy_into(qa, q0)
    copy_into(pa, p0)
    vprev = scratch(sc.ndof)
    total = 0
    ts = t
    hprev = 0.0
    for s in range(sc.stages.shape[0]):
        hs = sc.fracs[s] * h
        if s > 0:
            guess_from_node(sc, c, pa, v, J)
            if hprev != 0.0:
                rr = hs / hprev
                for i in range(sc.ndof):
                    v[i] += rr * (v[i] - vprev[i])
        it = explicit_step(sc, sc.stages[s], qa, pa, hs, ts, prm, ntol, maxit, v, q1, p1, c, cn, r, J)
        copy_into(vprev, v)
        hprev = hs
        if it < 0:
            return it - total
        total += it
        ts += hs
        copy_into(qa, q1)
        copy_into(pa, p1)
        c, cn = cn, c
    copy_into(vlast, v)
    return total
'''

LOOP = '''
import math
from numba import njit
from vcirun.codegen.frame import borrow, scratch
from PKG.linalg import copy_into
from PKG.steps import ld_step


@njit(cache=True, nogil=True, error_model="numpy")
def _finite(x):
    for i in range(x.shape[0]):
        if not math.isfinite(x[i]):
            return False
    return True


@njit(cache=True, nogil=True, error_model="numpy")
def integrate(sc, q0, p0, t0, h, N, prm, ntol, maxit, Q, P, iters):
    Q = borrow(Q)
    P = borrow(P)
    prm = borrow(prm)
    q = scratch(sc.ndof)
    p = scratch(sc.ndof)
    qt = scratch(sc.ndof)
    pt = scratch(sc.ndof)
    vt = scratch(sc.ndof)
    copy_into(q, q0)
    copy_into(p, p0)
    for j in range(sc.ndof):
        Q[0, j] = q[j]
        P[0, j] = p[j]
    i = 0
    while i < N:
        it = ld_step(sc, q, p, h, t0 + i * h, prm, ntol, maxit, qt, pt, vt)
        if it < 0:
            break
        copy_into(q, qt)
        copy_into(p, pt)
        if not (_finite(q) and _finite(p)):
            break
        iters[i] = it
        for j in range(sc.ndof):
            Q[i + 1, j] = q[j]
            P[i + 1, j] = p[j]
        i += 1
    return i
'''

# the global form: no `sc` parameter or argument; each field a slot read (indices of main's layout)
FIELDS = {"ndof": "NDOF", "node_len": "NODE_LEN", "band": "BAND"}


def global_form(text: str, slot: dict) -> str:
    text = re.sub(r"\bsc, ", "", text)
    for f, s in FIELDS.items():
        text = text.replace(f"sc.{f}", f"slot({slot[s]})")
    text = text.replace("sc.stages", f"carray(i8ptr(slot({slot['FULL_STAGES']})), (slot({slot['FULL_STAGES.len']}),))")
    text = text.replace("sc.fracs", f"carray(f8ptr(slot({slot['FULL_FRACS']})), (slot({slot['FULL_FRACS.len']}),))")
    text = text.replace("sc.k_node_M", f"slot({slot['sys_node_M']})").replace("sc.k_node", f"slot({slot['sys_node']})")
    text = text.replace("sc.k_pmjc[sid]", f"slot({slot['PmJc_0']} + sid)").replace("sc.k_ppc[sid]", f"slot({slot['Ppc_0']} + sid)")
    text = text.replace("from numba import njit", "from numba import carray, njit\nfrom vcirun.codegen.kcall import f8ptr, i8ptr, slot")
    return text


def write_package(root: Path, name: str, slot: dict | None) -> None:
    pkg = root / name
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    for mod, text in (("linalg", LINALG), ("table", TABLE), ("steps", STEPS), ("loop", LOOP)):
        text = text.replace("PKG", name)
        if slot is not None and mod != "linalg":
            text = global_form(text, slot)
        (pkg / f"{mod}.py").write_text(text)


CASE_METHODS = {"CVA": "SVC", "MCVAA": "SVA"}


def scene_table(case: str, method: str):
    """(module, slot values, slot index) of the shared build's linked module of (case, method)."""
    import vcirun
    from vcirun.codegen import shared
    from vcirun.run import plan as P

    vcirun.simulate(case, method, h=1e-2, T=0.02)
    p = P.plan(case, method, h=1e-2, T=5.0, start={})
    mod = p.module()
    return p, mod, list(mod.SCENE_SLOTS.values), dict(shared.SLOT)


def child(args):
    """One measurement process: {'compile_s', 'ms': {...}} for the packages in args.pkgs."""
    import numpy as np
    from numba import typed  # noqa: F401 (numba warm)

    sys.path.insert(0, args.root)
    out = {}
    rows = {}
    for case in args.cases.split(","):
        for method in args.methods.split(","):
            p, mod, values, slot = scene_table(case, method)
            prm = p.sysd.param_values(None)
            from vcirun.run import plan as P

            q0, p0 = P.ready_start(p, mod, P.start_state(p.sysd, None, None, None, prm, None), prm)
            N = p.N
            n = p.sysd.n
            Q, Pm, its = np.empty((N + 1, n)), np.empty((N + 1, n)), np.zeros(N, np.int64)
            ntol, maxit = float(p.tol["newton_tol"]), int(p.tol["max_iter"])
            k = {name: values[i] for name, i in slot.items()}
            times = {}
            stages = np.ascontiguousarray(mod.FULL_STAGES, dtype=np.int64)
            fracs = np.ascontiguousarray(mod.FULL_FRACS, dtype=np.float64)
            runs = {}
            for pkg in args.pkgs.split(","):
                loop = __import__(f"{pkg}.loop", fromlist=["integrate"])
                table = __import__(f"{pkg}.table", fromlist=["Scene"])
                sc = table.Scene(int(mod.NDOF), int(mod.NODE_LEN), int(mod.BAND), stages, fracs, k["sys_node"],
                                 k["sys_node_M"], np.array([k[f"PmJc_{i}"] for i in range(4)], dtype=np.int64),
                                 np.array([k[f"Ppc_{i}"] for i in range(4)], dtype=np.int64))
                lead = (sc,) if pkg == "vk_arg" else ()   # (the global form reads the installed slot table)
                runs[pkg] = (lambda f=loop.integrate, lead=lead: f(*lead, q0, p0, 0.0, p.h, N, prm, ntol, maxit, Q, Pm,
                                                                   its))
                mod.SCENE_SLOTS.install()
                t0, c0 = time.perf_counter(), time.process_time()
                steps = runs[pkg]()
                times[pkg] = {"first_s": time.perf_counter() - t0, "first_cpu_s": time.process_time() - c0,
                              "q_end": Q[N].tolist()}
                assert steps == N, (pkg, steps)
            # the shared core's own loop on the same work (constraint ignored, no energies)
            from vcirun.core import record

            settings = record.settings_vector(constrained=0, newton_tol=ntol, max_iter=maxit,
                                              event_tol=float(p.tol["event_tol"]),
                                              max_impacts_step=float(p.tol["max_impacts_step"]), energies=0,
                                              resting_contact=0)
            buf = record.allocate(N, n, int(mod.NCON))
            info = np.zeros(len(record.COUNTERS), np.int64)
            runs["core"] = lambda: mod.integrate(q0, p0, 0.0, p.h, N, prm, settings, buf, info)
            runs["core"]()
            times["core"] = {"q_end": buf[0][N].tolist()}
            ts = {key: [] for key in runs}
            for _ in range(args.repeats):   # interleaved: a slow spell of the machine hits every variant
                for key, f in runs.items():
                    mod.SCENE_SLOTS.install()
                    t0 = time.perf_counter()
                    f()
                    ts[key].append(time.perf_counter() - t0)
            for key in runs:
                times[key] |= {"ms": statistics.median(ts[key]) * 1e3, "min_ms": min(ts[key]) * 1e3}
            rows[f"{case}/{method}"] = times
    out["rows"] = rows
    print(json.dumps(out))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="cart_pendulum,link_chain_10")
    ap.add_argument("--methods", default="CVA,MCVAA")
    ap.add_argument("--repeats", type=int, default=31)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--root", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--pkgs", default="vk_arg,vk_glob", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        child(a)
        return
    from vcirun.codegen import shared

    root = Path(tempfile.mkdtemp(prefix="vk_proto_"))
    write_package(root, "vk_arg", None)
    write_package(root, "vk_glob", dict(shared.SLOT))
    print(f"prototype packages in {root} (vk_arg: the kernel table an argument; vk_glob: the slot table)")
    here = Path(__file__).resolve()
    results = {}
    for label, pkgs in (("cold+warm", None),):
        for pkg in ("vk_arg", "vk_glob"):
            for phase in ("cold", "warm"):
                env = dict(os.environ, NUMBA_CACHE_DIR=str(root / f"numba_{pkg}"), VCIRUN_TIER="compiled")
                t0 = time.perf_counter()
                r = subprocess.run([sys.executable, str(here), "--child", "--root", str(root), "--pkgs", pkg,
                                    "--cases", a.cases.split(",")[0], "--methods", "CVA", "--repeats", "3"],
                                   capture_output=True, text=True, env=env)
                if r.returncode:
                    print(r.stderr[-3000:])
                    raise SystemExit(1)
                row = json.loads(r.stdout.strip().splitlines()[-1])["rows"]
                first = next(iter(row.values()))[pkg]
                results[f"{pkg}/{phase}"] = first
                print(f"  {pkg:8s} {phase}: first call (compile or cache load) {first['first_s']:6.2f} s wall, "
                      f"{first['first_cpu_s']:6.2f} s CPU (process {time.perf_counter() - t0:.1f} s, load "
                      f"{os.getloadavg()[0]:.1f})", flush=True)
    # (the scene's compiled kernels are linked by address: the compiled tier, built here if missing)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(root / "numba_loop"), VCIRUN_TIER="compiled")
    r = subprocess.run([sys.executable, str(here), "--child", "--root", str(root), "--cases", a.cases,
                        "--methods", a.methods, "--repeats", str(a.repeats)], capture_output=True, text=True, env=env)
    if r.returncode:
        print(r.stderr[-3000:])
        raise SystemExit(1)
    rows = json.loads(r.stdout.strip().splitlines()[-1])["rows"]
    print(f"  loop ms per run (median of {a.repeats}), T = 5, constraint ignored; ratios to the shared core's integrate:")
    for key, t in rows.items():
        same = t["vk_arg"]["q_end"] == t["vk_glob"]["q_end"] == t["core"]["q_end"]
        for stat in ("ms", "min_ms"):
            print(f"    {key:22s} {'median' if stat == 'ms' else 'min':6s} core {t['core'][stat]:8.3f}  argument "
                  f"{t['vk_arg'][stat]:8.3f} (x{t['vk_arg'][stat] / t['core'][stat]:.3f}, x"
                  f"{t['vk_arg'][stat] / t['vk_glob'][stat]:.3f} of global)  global {t['vk_glob'][stat]:8.3f} "
                  f"(x{t['vk_glob'][stat] / t['core'][stat]:.3f})  same q(T): {same}", flush=True)
    results["loop"] = rows
    print(json.dumps({k: v for k, v in results.items() if k != "loop"}))


if __name__ == "__main__":
    main()
