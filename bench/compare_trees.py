"""Two checkouts of vcirun, one process: loop time of the same runs, interleaved, and bit-for-bit check.

    python bench/compare_trees.py OLD_TREE [--system cart_pendulum] [--methods CVA,CVA4,CVA8]
                                  [--h 0.2,0.05,0.01] [--T 5] [--repeats 41]

OLD_TREE is a checkout of another commit (e.g. `git worktree add /tmp/old <commit>`). Each tree's
kernel module is generated (or found) by a subprocess running that tree with its own cache
(OLD_TREE/.vcirun_cache, this tree's $VCIRUN_CACHE_DIR), then both modules are loaded here and run
by this tree's `vcirun.simulate`, alternating old/new `--repeats` times (a slow spell of the shared
machine hits both). Printed per (method, h): median loop time (`traj.wall_time`) of each, the ratio,
whether q and p agree bit for bit, and the Newton iteration totals. Both modules must have the
integrate signature of this tree's simulate, or the positional one before issue 16 (adapted).
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def module_path(tree: Path, cache: str, system: str, method: str, beta) -> str:
    """The kernel module file of (system, method) as `tree` generates it."""
    code = (f"import vcirun\nfrom vcirun.codegen import build\n"
            f"vcirun.simulate({system!r}, {method!r}, h=0.1, T=0.2, beta={beta!r})\n"
            f"print(build.cache_dir() / ('vk_' + build.BUILD_LOG[-1]['key'] + '.py'))\n")
    env = dict(os.environ, VCIRUN_CACHE_DIR=cache, PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, "-c", code], env=env, cwd=tree, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"{tree}: {r.stderr.strip()[-2000:]}")
    return r.stdout.strip().splitlines()[-1]


def load(path: str):
    key = Path(path).stem[3:]
    spec = importlib.util.spec_from_file_location(f"vcirun_kernels_{key}", path)  # the name numba's cache knows
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    if not hasattr(mod, "mass_matrix_ok"):  # modules before 2026-12-01 lack the compiled check simulate calls
        mod.mass_matrix_ok = lambda q, prm, A, m=mod: (m.sys_M(q, prm, A), True)[1]
    if not hasattr(mod, "O_Q"):  # before issue 16: positional outputs; adapt to the record ABI
        mod = _PositionalLoop(mod)
    return mod


class _PositionalLoop:
    """A module of the positional ABI (integrate with 25 arguments, before issue 16) behind the
    record ABI integrate(q0, p0, t0, h, N, prm, settings, out, info) of this tree. The adapter costs
    one Python call (~1 us) inside the timed region, against the old module."""

    def __init__(self, mod):
        self._mod = mod

    def __getattr__(self, name):
        return getattr(self._mod, name)

    def integrate(self, q0, p0, t0, h, N, prm, settings, out, info):
        from vcirun import record

        S = dict(zip(record.SETTINGS, settings))
        o = dict(zip([f.name for f in record.FIELDS], out))
        self._mod.integrate(q0, p0, t0, h, N, prm, bool(S["constrained"]), S["newton_tol"], int(S["max_iter"]),
                            S["event_tol"], int(S["max_impacts_step"]), o["q"], o["p"], o["H"], o["Ed"], o["Hmod"],
                            o["impacts"], o["impact_q"], o["impact_p_minus"], o["impact_p_plus"], o["impact_step"],
                            o["partial_steps"], o["newton_iters"], info, bool(S["energies"]))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old_tree", type=Path)
    ap.add_argument("--system", default="cart_pendulum")
    ap.add_argument("--methods", default="CVA,CVA4,CVA8")
    ap.add_argument("--h", default="0.2,0.05,0.01")
    ap.add_argument("--T", type=float, default=5.0)
    ap.add_argument("--repeats", type=int, default=41)
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import vcirun
    from vcirun import resolve

    beta = 3.2 if a.system == "cart_pendulum" else None
    new_cache = os.environ.get("VCIRUN_CACHE_DIR", str(Path.home() / ".cache" / "vcirun"))
    for method in a.methods.split(","):
        mods = {"old": load(module_path(a.old_tree.resolve(), str(a.old_tree.resolve() / ".vcirun_cache"), a.system,
                                        method, beta)),
                "new": load(module_path(ROOT, new_cache, a.system, method, beta))}
        for h in (float(x) for x in a.h.split(",")):
            times = {"old": [], "new": []}
            last = {}
            orig = resolve.load_module
            try:
                for _ in range(a.repeats):
                    for tag, mod in mods.items():
                        resolve.load_module = lambda s, k, m=mod: m   # a substitute loader: no warm index
                        tr = vcirun.simulate(a.system, method, h=h, T=a.T, beta=beta, energies=False)
                        times[tag].append(tr.wall_time)
                        last[tag] = tr
            finally:
                resolve.load_module = orig
            med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
            o, n = last["old"], last["new"]
            same = np.array_equal(o.q, n.q) and np.array_equal(o.p, n.p)
            diff = "bit for bit" if same else f"max |dq| {np.max(np.abs(o.q - n.q)):.2e}"
            print(f"{a.system} {method} h={h:g}: loop old {med['old']:.4f} ms, new {med['new']:.4f} ms, "
                  f"old/new {med['old'] / med['new']:.2f}; {diff}; Newton iterations {o.newton_iters.sum()} / "
                  f"{n.newton_iters.sum()}; status {o.status} / {n.status}", flush=True)


if __name__ == "__main__":
    main()
