"""First results in seconds: the targets of tiered execution, measured in one run (`make bench
BENCH_ARGS="--only tiers"`, or `python bench/tiers.py [--quick] [--skip-make]`).

Rows (each in fresh processes, each with an empty kernel cache where it says so):
  make run     `make run` in a fresh clone of HEAD (git clone into a temporary directory, an empty
               VCIRUN_CACHE_DIR; pip's cache as it is): to the end of `vcirun plot`
  simulate     the first `vcirun simulate --method MCVAA` (cart-pendulum) on an empty cache: the
               process's wall time, and when its compiled tier was ready (the background compile)
  new scene    the first `vcirun simulate --system docs/examples/rocking_block.yaml --h 1e-3 --T 2` with
               its core not cached (an empty cache)
  fig4         `vcirun sweep configs/fig4.yaml` to its last run on an empty cache: today's pipeline
               (VCIRUN_TIER=compiled: cold kernels compiled side by side, then the runs) against the
               auto tier (interpreted runs at once, compiled in the background)
  throughput   the compiled tier once compiled, against /work/main (or $VCIRUN_BASE_TREE) on the same warm
               cache: the cart-pendulum loop (traj.wall_time) and whole simulate() call of CVA and MCVAA,
               medians of 21; the warm fig4 sweep
Wall seconds on a shared machine: the load average is printed with each row, CPU seconds beside.
"""
from __future__ import annotations

import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BASE = Path(os.environ.get("VCIRUN_BASE_TREE", "/work/main"))


def _load() -> str:
    return f"load {os.getloadavg()[0]:.1f}"


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(cmd, env, cwd, timeout=3600) -> dict:
    c0, t0 = _cpu_children(), time.perf_counter()
    r = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    return {"wall_s": time.perf_counter() - t0, "cpu_s": _cpu_children() - c0, "returncode": r.returncode,
            "stdout": r.stdout, "stderr": r.stderr, "load": os.getloadavg()[0]}


# Python's bytecode as a user has it after the first import (pip installs with --no-compile; Python
# writes each module's .pyc when it first imports it): written once under a prefix of this benchmark
# (a shell with PYTHONDONTWRITEBYTECODE would otherwise compile sympy, numba and scipy from source in
# every process), warmed by `_warm_bytecode` before the rows that measure a first simulation.
PYCACHE = Path(tempfile.gettempdir()) / "vcirun_bench_pycache"


def _env(cache: Path, tree: Path = ROOT, **extra) -> dict:
    env = dict(os.environ, VCIRUN_CACHE_DIR=str(cache), PYTHONPATH=str(tree), PYTHONPYCACHEPREFIX=str(PYCACHE))
    env.pop("VCIRUN_TIER", None)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    env.update(extra)
    return env


def _warm_bytecode(log) -> None:
    """Import everything a first simulation and a sweep import, once (bytecode, not kernels)."""
    code = ("import vcirun, vcirun.run.api, vcirun.cli.main, vcirun.experiments.sweep, vcirun.codegen.derive, "
            "vcirun.codegen.mh_kernels, vcirun.reference_solution.exact, vcirun.codegen.background, sympy, scipy.integrate")
    with tempfile.TemporaryDirectory() as d:
        r = _run([sys.executable, "-c", code], _env(Path(d)), ROOT)
    log(f"  (bytecode of the imported modules written under {PYCACHE}: {r['wall_s']:.1f} s)")


def _wait_ready(cache: Path, timeout: float = 1800.0) -> float:
    """Seconds until no background compile holds a lock in `cache` (its compiled tiers are ready)."""
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < timeout:
        r = subprocess.run([sys.executable, "-m", "vcirun.cli.main", "cache", "info"], env=_env(cache),
                           capture_output=True, text=True, cwd=ROOT)
        if "being compiled:" not in r.stdout:
            return time.perf_counter() - t0
        time.sleep(1.0)
    return float("nan")


def row_make_run(log, timeout=3600) -> dict:
    with tempfile.TemporaryDirectory(prefix="vcirun_clone_") as d:
        clone = Path(d) / "vcirun"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        env = {k: v for k, v in os.environ.items()
               if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPATH", "VCIRUN_TIER", "PYTHONPYCACHEPREFIX")}
        r = _run(["make", "run"], dict(env, VCIRUN_CACHE_DIR=str(Path(d) / "cache")), clone, timeout)
        out = {k: r[k] for k in ("wall_s", "cpu_s", "returncode", "load")}
        if r["returncode"]:
            out["error"] = (r["stderr"].strip().splitlines() or ["?"])[-1]
        out["ready_after_s"] = _wait_ready(Path(d) / "cache")
    log(f"  make run (fresh clone, empty cache)   {out['wall_s']:7.1f} s  (cpu {out['cpu_s']:.1f} s, "
        f"{'ok' if not out['returncode'] else out.get('error')}; compiled tier ready {out['ready_after_s']:.0f} s "
        f"later; load {out['load']:.1f})")
    return out


def row_first_simulate(log, args, label) -> dict:
    with tempfile.TemporaryDirectory(prefix="vcirun_tier_") as d:
        cache = Path(d) / "cache"
        r = _run([sys.executable, "-m", "vcirun.cli.main", "simulate", *args], _env(cache), ROOT)
        ready = _wait_ready(cache)
        warm = _run([sys.executable, "-m", "vcirun.cli.main", "simulate", *args], _env(cache), ROOT)
    tier = [l for l in r["stderr"].splitlines() if "tier" in l]
    out = {"wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "returncode": r["returncode"], "load": r["load"],
           "tier_line": tier[0] if tier else "", "compiled_ready_after_s": ready + 0.0,
           "next_process_wall_s": warm["wall_s"], "next_process_stderr": warm["stderr"].strip()}
    log(f"  {label:38s} {r['wall_s']:7.2f} s  (cpu {r['cpu_s']:.1f} s; compiled tier ready {ready:.0f} s later; "
        f"the next process {warm['wall_s']:.2f} s; load {r['load']:.1f})")
    return out


def row_fig4(log, quick=False) -> dict:
    cfg = "configs/quick.yaml" if quick else "configs/fig4.yaml"
    out = {}
    for tier in ("compiled", "auto"):
        with tempfile.TemporaryDirectory(prefix="vcirun_fig4_") as d:
            cache = Path(d) / "cache"
            env = _env(cache, **({"VCIRUN_TIER": tier} if tier == "compiled" else {}))
            r = _run([sys.executable, "-m", "vcirun.cli.main", "sweep", cfg, "--output", str(Path(d) / "f.h5"),
                      "--force", "--quiet"], env, ROOT)
            line = (r["stdout"].strip().splitlines() or [""])[0]
            notes = [l for l in r["stdout"].splitlines() if "interpreted tier" in l]
            out[tier] = {"wall_s": r["wall_s"], "cpu_s": r["cpu_s"], "returncode": r["returncode"], "load": r["load"],
                         "summary": line, "note": notes[0] if notes else "", "ready_after_s": _wait_ready(cache)}
            log(f"  {cfg} empty cache, {tier:8s}  {r['wall_s']:7.1f} s  (cpu {r['cpu_s']:.1f} s; load "
                f"{r['load']:.1f})  {line}")
    out["ratio"] = out["auto"]["wall_s"] / out["compiled"]["wall_s"]
    log(f"  auto / today: {out['ratio']:.2f} (target <= 0.5)")
    return out


_LOOP = r"""
import json, statistics, sys, time, warnings
warnings.simplefilter("ignore")
import vcirun
out = {}
for m in ("CVA", "MCVAA"):
    kw = dict(h=1e-2, T=5.0, beta=3.2)
    if "tier" in vcirun.simulate.__code__.co_varnames:
        kw["tier"] = "compiled"
    vcirun.simulate("cart_pendulum", m, **kw)
    loops, calls = [], []
    for _ in range(21):
        t0 = time.perf_counter()
        tr = vcirun.simulate("cart_pendulum", m, **kw)
        calls.append(time.perf_counter() - t0)
        loops.append(tr.wall_time)
    out[m] = {"loop_ms": 1e3 * statistics.median(loops), "call_ms": 1e3 * statistics.median(calls)}
print(json.dumps(out))
"""


def row_throughput(log, quick=False) -> dict:
    out = {}
    cache = Path(os.environ.get("VCIRUN_CACHE_DIR", Path.home() / ".cache" / "vcirun"))
    for name, tree in (("this tree", ROOT), (f"base {BASE}", BASE)):
        if not (tree / "vcirun").is_dir():
            continue
        rows = []
        for _ in range(1 if quick else 3):   # three processes per tree: the median
            r = _run([sys.executable, "-c", _LOOP], _env(cache, tree, VCIRUN_TIER="compiled"), tree)
            if r["returncode"]:
                rows.append({"error": (r["stderr"].strip().splitlines() or ["?"])[-1]})
                break
            rows.append(json.loads(r["stdout"].strip().splitlines()[-1]))
        ok = [x for x in rows if "error" not in x]
        if not ok:
            out[name] = rows[-1]
            log(f"  {name}: {rows[-1]}")
            continue
        med = {m: {k: sorted(x[m][k] for x in ok)[len(ok) // 2] for k in ("loop_ms", "call_ms")} for m in ok[0]}
        out[name] = med
        log(f"  {name:28s} " + "  ".join(f"{m} loop {v['loop_ms']:.3f} ms call {v['call_ms']:.3f} ms"
                                       for m, v in med.items()) + f"  ({_load()})")
    return out


def section_tiers(res, quick=False, skip_make=False, log=print):
    log("== tiers: first results in seconds (interpreted at once, compiled in the background)")
    out = {"load_start": os.getloadavg()[0]}
    _warm_bytecode(log)
    if not skip_make and shutil.which("make") and shutil.which("git"):
        out["make_run"] = row_make_run(log)
    out["first_simulate_mcvaa"] = row_first_simulate(log, ["--method", "MCVAA"], "first simulate MCVAA (empty cache)")
    out["first_rocking_block"] = row_first_simulate(
        log, ["--system", "docs/examples/rocking_block.yaml", "--h", "1e-3", "--T", "2"],
        "first simulate rocking block (empty)")
    out["fig4"] = row_fig4(log, quick)
    out["throughput"] = row_throughput(log, quick)
    out["load_end"] = os.getloadavg()[0]
    res["tiers"] = out
    return out


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="configs/quick.yaml for the sweep row, one throughput process")
    ap.add_argument("--skip-make", action="store_true", help="leave out the `make run` row")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_tiers.json"))
    a = ap.parse_args(argv)
    res = {}
    section_tiers(res, quick=a.quick, skip_make=a.skip_make)
    Path(a.out).parent.mkdir(exist_ok=True)
    Path(a.out).write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
