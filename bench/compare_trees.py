"""Two checkouts of vcirun, one process: loop time of the same runs, interleaved, and bit-for-bit check.

    python bench/compare_trees.py OLD_TREE [--system cart_pendulum[,double_pendulum]]
                                  [--methods CVA,CVA4,CVA8] [--h 0.2,0.05,0.01] [--T 5] [--beta 3.2]
                                  [--repeats 41] [--call-overhead R] [--resting-contact on|off]
                                  [--modules OLD.py,NEW.py] [--nrt-count] [--json OUT.json]

OLD_TREE is a checkout of another commit (e.g. `git worktree add /tmp/old <commit>`). Each tree's
kernel module is generated (or found) by a subprocess running that tree with its own cache
(OLD_TREE/.vcirun_cache, this tree's $VCIRUN_CACHE_DIR), then both modules are loaded here and run
by this tree's `vcirun.simulate`, alternating old/new `--repeats` times (a slow spell of the shared
machine hits both; who goes first alternates). The generated module is self-contained (the numba
units are part of its text): the old module runs the old tree's compiled loop, only the Python
around it is this tree's.

Loop time is measured around the module's compiled `integrate` call alone, for both modules, by the
same thin wrapper (`_Timed`): for an old module behind the adapter below, the adapter's Python
(building its positional arguments from the record tuple) lies outside the timed region. Printed per
(system, method, h): median loop time of each, the ratio new/old, the minima and their ratio, the
medians of `traj.wall_time`
(this tree's timed region: buffer allocation + the call; for an old module it includes the
adapter's ~us of Python), whether q and p agree bit for bit (else max |dq|, |dp|), the impact count
and times, the Newton iteration totals, the statuses. --call-overhead adds one-step runs (the fixed
cost of a call, hence a per-step figure); --nrt-count counts numba's reference-count calls in each
loop under gdb (see nrt_count); --modules compares two module files directly (e.g. a hand-edited
copy of a generated module, to test where a difference comes from).

Module ABIs understood:
- the record ABI of this tree: integrate(q0, p0, t0, h, N, prm, settings, out, info), `out` the
  tuple of vcirun.core.record.FIELDS, NCON constraints (sys_phis/sys_dphis);
- the positional ABI (trees up to 624193a: integrate with 25 arguments, one constraint
  sys_phi/sys_dphi, info of 5 counters, no held contacts, no impact_contact/impact_impulse), adapted
  by `_PositionalLoop`: the rows the old loop has no buffer for keep their fill (contact_active
  False, contact_force 0, no releases), impact_contact is set to 0 (the one constraint) and
  impact_impulse to NaN after the call (outside the timed region). The old loop has no resting
  contact: compare runs where this tree holds no contact (elastic impacts: none is held).
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def module_path(tree: Path, cache: str, system: str, method: str, beta) -> str:
    """The kernel module file of (system, method) as `tree` generates it."""
    code = (f"import vcirun\nfrom vcirun.codegen import build\n"
            f"run = lambda: vcirun.simulate({system!r}, {method!r}, h=0.1, T=0.2, beta={beta!r})\n"
            "try:\n    from vcirun.codegen.kernel_cache import default\n"
            "except ImportError:   # a tree with the build log as a module list\n"
            "    run(); key = build.BUILD_LOG[-1]['key']\n"
            "else:\n    with default().report() as built:\n        run()\n    key = built.entries[-1]['key']\n"
            "print(build.cache_dir() / ('vk_' + key + '.py'))\n")
    env = dict(os.environ, VCIRUN_CACHE_DIR=cache, PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, "-c", code], env=env, cwd=tree, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"{tree}: {r.stderr.strip()[-2000:]}")
    return r.stdout.strip().splitlines()[-1]


def load(path: str, method: str | None = None):
    key = Path(path).stem[3:]
    with open(path) as f:
        shared_scene = f.readline().startswith("# vcirun scene module")
    if shared_scene:
        # a scene module of the shared build: linked to THIS tree's core of the method's
        # kernel set (for an OLD_TREE of the shared build, run it with VCIRUN_BUILD=specialized)
        from vcirun.codegen.kernel_cache import default
        from vcirun.methods.table import resolve_method

        ks = resolve_method(method).kernel_set()
        return _Timed(default()._exec_module(key, Path(path), Path(path).read_text(), "compare_trees", ks, True, 0.0,
                                             False), "record")
    spec = importlib.util.spec_from_file_location(f"vcirun_kernels_{key}", path)  # the name numba's cache knows
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    if not hasattr(mod, "mass_matrix_ok"):  # modules before 2026-12-01 lack the compiled check simulate calls
        mod.mass_matrix_ok = lambda q, prm, A, m=mod: (m.sys_M(q, prm, A), True)[1]
    if not hasattr(mod, "O_Q"):  # a tree up to 624193a: positional outputs; adapt to the record ABI
        return _Timed(_PositionalLoop(mod), "positional")
    return _Timed(mod, "record")


class _Timed:
    """A module whose integrate is timed around the compiled call alone (`last`: seconds of the
    last call). The same wrapper for both trees, so both loop times carry the same overhead."""

    def __init__(self, mod, abi):
        self._mod = mod
        self.abi = abi
        self.last = float("nan")

    def __getattr__(self, name):
        return getattr(self._mod, name)

    def integrate(self, q0, p0, t0, h, N, prm, settings, out, info):
        if isinstance(self._mod, _PositionalLoop):
            self.last = self._mod.integrate_timed(q0, p0, t0, h, N, prm, settings, out, info)
            return
        f = self._mod.integrate
        t = time.perf_counter()
        f(q0, p0, t0, h, N, prm, settings, out, info)
        self.last = time.perf_counter() - t


class _PositionalLoop:
    """A module of the positional ABI (integrate with 25 arguments; trees up to 624193a) behind the
    record ABI integrate(q0, p0, t0, h, N, prm, settings, out, info) of this tree, one constraint
    (NCON = 1, sys_phis/sys_dphis over sys_phi/sys_dphi). `integrate_timed` builds the positional
    arguments, then times the old module's compiled call alone."""

    NCON = 1

    def __init__(self, mod):
        self._mod = mod

    def __getattr__(self, name):
        return getattr(self._mod, name)

    def sys_phis(self, q, prm, out):
        out[0] = self._mod.sys_phi(q, prm)

    def sys_dphis(self, q, prm, G):
        g = np.empty(G.shape[1])
        self._mod.sys_dphi(q, prm, g)
        G[0, :] = g

    def integrate(self, q0, p0, t0, h, N, prm, settings, out, info):
        self.integrate_timed(q0, p0, t0, h, N, prm, settings, out, info)

    def integrate_timed(self, q0, p0, t0, h, N, prm, settings, out, info) -> float:
        from vcirun.core import record

        S = dict(zip(record.SETTINGS, settings.tolist()))
        o = dict(zip([f.name for f in record.FIELDS], out))
        if int(S["resting_contact"]) and not hasattr(self._mod, "_vcirun_warned"):
            self._mod._vcirun_warned = True   # the old loop never holds a contact (said once per module)
            print("note: the old module has no resting contact (resting_contact ignored)", file=sys.stderr)
        old_info = info[:5]   # status, fail_step, n_impacts, n_partial, steps (n_releases stays 0)
        args = (q0, p0, t0, h, N, prm, bool(S["constrained"]), S["newton_tol"], int(S["max_iter"]),
                S["event_tol"], int(S["max_impacts_step"]), o["q"], o["p"], o["H"], o["Ed"], o["Hmod"],
                o["impacts"], o["impact_q"], o["impact_p_minus"], o["impact_p_plus"], o["impact_step"],
                o["partial_steps"], o["newton_iters"], old_info, bool(S["energies"]))
        f = self._mod.integrate
        t = time.perf_counter()
        f(*args)
        dt = time.perf_counter() - t
        k = int(old_info[2])
        o["impact_contact"][:k] = 0
        o["impact_impulse"][:k] = np.nan
        return dt


def _diff(a, b) -> float:
    if a is None or b is None:
        return float("nan")
    if a.shape != b.shape:
        return float("inf")
    return float(np.max(np.abs(a - b))) if a.size else 0.0


def compare(system, method, h, T, beta, mods, repeats, vcirun, resolve, quiet=False, resting=True) -> dict:
    loop = {"old": [], "new": []}
    wall = {"old": [], "new": []}
    last = {}
    for r in range(repeats):
        for tag in (("old", "new") if r % 2 == 0 else ("new", "old")):   # alternate who goes first
            mod = mods[tag]
            tr = vcirun.simulate(system, method, h=h, T=T, beta=beta, energies=False, resting_contact=resting,
                                 loader=lambda s, k, m=mod: m)   # a substitute loader: no warm index
            loop[tag].append(mod.last)
            wall[tag].append(tr.wall_time)
            last[tag] = tr
    o, n = last["old"], last["new"]
    med = {k: statistics.median(v) * 1e3 for k, v in loop.items()}
    medw = {k: statistics.median(v) * 1e3 for k, v in wall.items()}
    same = (o.q.shape == n.q.shape and np.array_equal(o.q, n.q) and np.array_equal(o.p, n.p))
    row = dict(system=system, method=method, h=h, T=T, beta=beta, repeats=repeats,
               loop_old_ms=med["old"], loop_new_ms=med["new"], ratio_new_old=med["new"] / med["old"],
               wall_old_ms=medw["old"], wall_new_ms=medw["new"],
               loop_old_min_ms=min(loop["old"]) * 1e3, loop_new_min_ms=min(loop["new"]) * 1e3,
               bit_for_bit=bool(same), max_dq=_diff(o.q, n.q), max_dp=_diff(o.p, n.p),
               impacts_old=int(o.impacts.size), impacts_new=int(n.impacts.size),
               max_dt_impact=_diff(o.impacts, n.impacts),
               newton_old=int(o.newton_iters.sum()), newton_new=int(n.newton_iters.sum()),
               status_old=o.status, status_new=n.status)
    if quiet:
        return row
    diff = "bit for bit" if same else f"max |dq| {row['max_dq']:.2e}, |dp| {row['max_dp']:.2e}"
    print(f"{system} {method} h={h:g}: loop old {med['old']:.4f} ms, new {med['new']:.4f} ms, new/old "
          f"{row['ratio_new_old']:.3f} (min old {row['loop_old_min_ms']:.4f}, new {row['loop_new_min_ms']:.4f}, "
          f"new/old "
          f"{row['loop_new_min_ms'] / row['loop_old_min_ms']:.3f}; wall_time old {medw['old']:.4f}, new "
          f"{medw['new']:.4f}); {diff}; "
          f"impacts {row['impacts_old']} / {row['impacts_new']} (max |dt| {row['max_dt_impact']:.1e}); "
          f"Newton iterations {row['newton_old']} / {row['newton_new']}; status {o.status} / {n.status}",
          flush=True)
    return row


# --- NRT reference counting (--nrt-count) ------------------------------------------------------
# numba's NRT_incref/NRT_decref are atomic operations; a loop that passes arrays (or a tuple of
# arrays) to a jitted function that is not inlined, or inlines one at the IR level, pays a pair per
# array. This counts the calls of one module's compiled integrate under gdb (breakpoints on the two
# functions, process stopped by SIGUSR1 between phases): a one-step call, then the N-step call, and
# the return address of each call (offsets from integrate's entry: a run of consecutive offsets
# with the same count is one call site, e.g. a tuple of arrays unpacked).

_GDB_SCRIPT = """
import gdb, json
counts, rets = {}, {}
class B(gdb.Breakpoint):
    def stop(self):
        counts[self.tag] = counts.get(self.tag, 0) + 1
        ra = int(gdb.parse_and_eval("*(unsigned long*)$rsp"))
        rets[ra] = rets.get(ra, 0) + 1
        return False
info = json.load(open(OUT + ".addr"))
for tag in ("incref", "decref"):
    b = B("*" + hex(info[tag]), internal=True)
    b.tag = tag
def report(tag):
    rec = {"counts": dict(counts), "sites": {str(ra - info["integrate"]): c for ra, c in rets.items()}}
    with open(OUT + "." + tag, "w") as f:
        json.dump(rec, f)
    counts.clear()
    rets.clear()
"""


def capture_loop(m, system, method, h, T, beta, resting=True):
    """(the compiled integrate of module m (a `load` result), the arguments `vcirun.simulate` gives it,
    the trajectory): to call the loop itself again (nrt_count, bench/profile_loop.py). An old module of
    the positional ABI sits one level further in; its positional arguments are captured."""
    import vcirun
    from vcirun.run import resolve

    holder = m._mod._mod if m.abi == "positional" else m._mod
    raw = holder.integrate
    captured = {}

    class _Capture:
        def __getattr__(self, name):
            return getattr(holder, name)

        def integrate(self, *args):
            captured["args"] = args
            return raw(*args)

    if m.abi == "positional":
        m._mod._mod = _Capture()
    else:
        m._mod = _Capture()
    try:
        tr = vcirun.simulate(system, method, h=h, T=T, beta=beta, energies=False, resting_contact=resting,
                             loader=lambda s, k: m)
    finally:
        if m.abi == "positional":
            m._mod._mod = holder
        else:
            m._mod = holder
    return raw, captured["args"], tr


def _nrt_child(path, system, method, h, T, beta, out, resting=True):
    """Run under gdb by nrt_count: stop (SIGUSR1) after setup, after a one-step call, after the N-step call."""
    import signal

    sys.path.insert(0, str(ROOT))
    from numba.core.runtime import nrt

    warnings.simplefilter("ignore")
    raw, args, tr = capture_loop(load(path, method), system, method, h, T, beta, resting)
    args = list(args)
    cres = next(iter(raw.overloads.values()))
    lib = nrt.rtsys.library
    info = {"incref": lib.get_pointer_to_function("NRT_incref"), "decref": lib.get_pointer_to_function("NRT_decref"),
            "integrate": cres.library.get_pointer_to_function(cres.fndesc.llvm_func_name),
            "N": args[4], "impacts": int(tr.impacts.size), "newton": int(tr.newton_iters.sum())}
    try:   # the JIT functions' entries (a module compiled in this process: see nrt_count), for per-function counts
        from profile_loop import jit_symbols

        info["symbols"] = [(a - info["integrate"], n) for a, n in jit_symbols(cres.library)]
    except Exception:
        info["symbols"] = []
    Path(out + ".addr").write_text(json.dumps(info))
    raw(*args)
    os.kill(os.getpid(), signal.SIGUSR1)
    one = list(args)
    one[4] = 1
    raw(*one)
    os.kill(os.getpid(), signal.SIGUSR1)
    raw(*args)
    os.kill(os.getpid(), signal.SIGUSR1)


def nrt_count(path, system, method, h, T, beta, resting=True) -> dict:
    """NRT_incref + NRT_decref calls of one module's integrate: one-step call, N-step call, the
    per-step and per-impact estimates ((N-step - one-step) / (N - 1) is per step including the
    impact steps' share), and the call sites (return-address offsets from integrate's entry)."""
    import tempfile

    out = tempfile.mktemp(prefix="nrtcount_")
    gscript = out + ".gdb.py"
    Path(gscript).write_text(f"OUT = {out!r}\n" + _GDB_SCRIPT)
    child = [sys.executable, str(Path(__file__).resolve()), "--nrt-child", path, system, method, repr(h), repr(T),
             repr(beta), out, "on" if resting else "off"]
    cmd = ["gdb", "-q", "-batch", "-ex", "set pagination off", "-ex", "handle SIGUSR1 stop print nopass",
           "-ex", "run", "-ex", f"source {gscript}", "-ex", "continue", "-ex", "python report('one')",
           "-ex", "continue", "-ex", "python report('full')", "-ex", "continue", "--args"] + child
    # a fresh numba cache: the child compiles the module, so its function symbols are known
    numba_cache = tempfile.mkdtemp(prefix="nrtcount_numba_")
    env = dict(os.environ, PYTHONPATH=f"{ROOT}{os.pathsep}{ROOT / 'bench'}", NUMBA_CACHE_DIR=numba_cache)
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, env=env)
    finally:
        shutil.rmtree(numba_cache, ignore_errors=True)
    try:
        info = json.loads(Path(out + ".addr").read_text())
        one = json.loads(Path(out + ".one").read_text())
        full = json.loads(Path(out + ".full").read_text())
    except OSError:
        raise SystemExit(f"nrt count failed for {path}:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
    finally:
        for ext in (".addr", ".one", ".full", ".gdb.py"):
            Path(out + ext).unlink(missing_ok=True)
    c1 = sum(one["counts"].values())
    cN = sum(full["counts"].values())
    N = info["N"]
    steady = sum(c for c in full["sites"].values() if c >= N - 1)   # sites hit (about) once per grid step
    by_fn = {}
    syms = info.get("symbols") or []
    if syms:
        import bisect

        starts = [s for s, _ in syms]
        for site, c in full["sites"].items():
            k = bisect.bisect_right(starts, int(site)) - 1
            name = syms[k][1] if k >= 0 else "?"
            by_fn[name] = by_fn.get(name, 0) + c
    return dict(N=N, impacts=info["impacts"], one_step=c1, full=cN, per_step=(cN - c1) / max(N - 1, 1),
                per_smooth_step=steady / N, rest=cN - steady,
                by_function=dict(sorted(by_fn.items(), key=lambda kv: -kv[1])),
                sites={k: v for k, v in sorted(full["sites"].items(), key=lambda kv: int(kv[0]))})


def main(argv=None):
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "--nrt-child":
        path, system, method, h, T, beta, out, resting = sys.argv[2:10]
        return _nrt_child(path, system, method, float(h), float(T), None if beta == "None" else float(beta), out,
                          resting == "on")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old_tree", type=Path)
    ap.add_argument("--system", default="cart_pendulum", help="comma-separated built-in scenes")
    ap.add_argument("--methods", default="CVA,CVA4,CVA8")
    ap.add_argument("--h", default="0.2,0.05,0.01")
    ap.add_argument("--T", type=float, default=5.0)
    ap.add_argument("--beta", type=float, default=3.2, help="beta of the cart-pendulum (other scenes: default start)")
    ap.add_argument("--repeats", type=int, default=41)
    ap.add_argument("--json", type=Path, default=None, help="write the rows here")
    ap.add_argument("--call-overhead", type=int, default=0, metavar="REPEATS",
                    help="also time one-step runs (T = h) this many times: the fixed cost of a loop call "
                         "(argument unboxing, setup), to split a difference into per-call and per-step parts")
    ap.add_argument("--modules", default=None, metavar="OLD.py,NEW.py",
                    help="module files to compare instead of generating them (one --system/--methods); "
                         "e.g. a hand-edited copy of a generated module to test where a difference comes from")
    ap.add_argument("--resting-contact", choices=("on", "off"), default="on",
                    help="simulate's resting_contact (default on, as simulate): off skips this tree's held-contact "
                         "work (the hold test after each impact); the old loop has none either way")
    ap.add_argument("--nrt-count", action="store_true",
                    help="also count numba's NRT_incref/NRT_decref calls in each module's loop (needs gdb): "
                         "per run, per grid step, and on the impact steps")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import vcirun
    from vcirun.run import resolve
    from vcirun.core.grid import GridWarning, grid_count

    warnings.simplefilter("ignore", GridWarning)   # T = 5 is not a multiple of 3.2e-2: N = 156 for both trees

    print(f"vcirun from {Path(vcirun.__file__).parent}; old tree {a.old_tree.resolve()}", flush=True)
    new_cache = os.environ.get("VCIRUN_CACHE_DIR", str(Path.home() / ".cache" / "vcirun"))
    rows = []
    for system in a.system.split(","):
        beta = a.beta if system == "cart_pendulum" else None
        for method in a.methods.split(","):
            if a.modules:
                po, pn = a.modules.split(",")
            else:
                po = module_path(a.old_tree.resolve(), str(a.old_tree.resolve() / ".vcirun_cache"), system, method,
                                 beta)
                pn = module_path(ROOT, new_cache, system, method, beta)
            mods = {"old": load(po, method), "new": load(pn, method)}
            po, pn = str(po), str(pn)
            print(f"{system} {method}: old module {mods['old'].__name__} ({mods['old'].abi} ABI), "
                  f"new {mods['new'].__name__} ({mods['new'].abi} ABI)", flush=True)
            for h in (float(x) for x in a.h.split(",")):
                rows.append(compare(system, method, h, a.T, beta, mods, a.repeats, vcirun, resolve,
                                    resting=a.resting_contact == "on"))
                if a.call_overhead:
                    one = compare(system, method, h, h, beta, mods, a.call_overhead, vcirun, resolve, quiet=True,
                                  resting=a.resting_contact == "on")
                    r = rows[-1]
                    r["call_old_ms"], r["call_new_ms"] = one["loop_old_ms"], one["loop_new_ms"]
                    N = grid_count(h, a.T)
                    r["step_old_us"] = (r["loop_old_ms"] - r["call_old_ms"]) / max(N - 1, 1) * 1e3
                    r["step_new_us"] = (r["loop_new_ms"] - r["call_new_ms"]) / max(N - 1, 1) * 1e3
                    print(f"    one-step call: old {r['call_old_ms'] * 1e3:.2f} us, "
                          f"new {r['call_new_ms'] * 1e3:.2f} us; "
                          f"per further step: old {r['step_old_us']:.4f} us, new {r['step_new_us']:.4f} us "
                          f"(new/old {r['step_new_us'] / r['step_old_us']:.3f})", flush=True)
                if a.nrt_count:
                    r = rows[-1]
                    for tag, pth in (("old", po), ("new", pn)):
                        c = nrt_count(pth, system, method, h, a.T, beta, a.resting_contact == "on")
                        r[f"nrt_{tag}"] = c
                    co, cn = r["nrt_old"], r["nrt_new"]
                    print(f"    NRT incref+decref calls: run old {co['full']}, new {cn['full']}; one-step call "
                          f"{co['one_step']} / {cn['one_step']}; per smooth step {co['per_smooth_step']:.1f} / "
                          f"{cn['per_smooth_step']:.1f}; the rest (impact steps, setup) {co['rest']} / {cn['rest']} "
                          f"({cn['impacts']} impacts)", flush=True)
                    for tag, c in (("old", co), ("new", cn)):
                        if c["by_function"]:
                            print(f"      {tag}, by calling function (per grid step): " + ", ".join(
                                f"{n} {v / c['N']:.2f}" for n, v in list(c["by_function"].items())[:10]))
                if a.json:
                    a.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
