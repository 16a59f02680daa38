"""`make bench` section `loop`: the engine loop's targets, this tree against a base tree, in one run.

    python bench/loop_targets.py [--base /work/main] [--rows yardstick,cradle,coldbuild] [--repeats 201]
                                 [--builds shared,specialized,auto] [--rounds 1]

Rows (each tree in its own fresh process, its own code on PYTHONPATH, the shared kernel cache):
  yardstick  cart-pendulum CVA, T = 5, h = 1e-2, beta = 3.2: vcirun's compiled loop (Trajectory.wall_time)
             and whole simulate() call against a hand-written allocation-free numba CVA loop
             (bench/handwritten_cva.py: the same trajectory, closed-form 2 x 2 mechanics), medians of
             interleaved calls
  kernels    the same, the hand-written loop calling the scene's generated kernels (the module vcirun
             runs) in place of the closed forms: the engine's cost alone
  cradle     newton_cradle_100 (99 contacts touching) CVA: CPU microseconds per smooth step before the
             first impact (h = 1e-4, T = 0.19; bench/bodies_scaling.py's measure)
  coldbuild  the first cart-pendulum CVA simulation with an empty kernel cache (VCIRUN_CACHE_DIR a fresh
             directory): the family's lean core and the scene's module compiled, CPU seconds of the
             process and its children (the C compiler)
The yardstick and kernels rows run in each build of --builds (VCIRUN_BUILD: the shared core, whose loop
calls the scene's kernels by address; the specialized module, one scene compiled with the loop; auto,
the default, which runs the specialized module once the scene has been hot on this machine, as after
the specialized row, and is measured for this tree only). Printed as a table with the targets of the
engine issue; never asserted. --rounds K measures every row K times (the trees alternating within each
round) and prints, per row, the round of median simulate() ratio (cradle, cold build: median time) with
the range over the rounds: this machine has slow phases of seconds to minutes that one round of 201
calls can fall in.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TARGETS = {"loop_ratio": 1.1, "call_ratio": 1.3, "cradle_us": 20.0}

_YARDSTICK = ("import json, sys; sys.path.insert(0, {bench!r}); import handwritten_cva as h; "
              "print(json.dumps(h.measure({n}, kernels={kernels})))")
_CRADLE = ("import json, sys; sys.path.insert(0, {bench!r}); import bodies_scaling as b; "
           "r = b.one('newton_cradle_100', 'CVA'); print(json.dumps({{k: r[k] for k in ('us_per_smooth_step', "
           "'smooth_steps', 'status_smooth')}}))")
_COLD = ("import json, resource, time; t = time.perf_counter(); import vcirun; "
         "tr = vcirun.simulate('cart_pendulum', 'CVA', h=1e-2, T=0.1); "
         "u = [resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]; "
         "print(json.dumps({'cpu_s': sum(x.ru_utime + x.ru_stime for x in u), 'wall_s': time.perf_counter() - t, "
         "'status': tr.status}))")


def _run(tree: Path, code: str, env_extra: dict | None = None, timeout: float = 7200) -> dict:
    # the compiled tier always: a row never times the interpreter while a background compile runs
    env = dict(os.environ, PYTHONPATH=str(tree), VCIRUN_TIER="compiled", **(env_extra or {}))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=str(tree),
                       timeout=timeout)
    if r.returncode:
        return {"error": (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def measure(base: Path, rows: list[str], repeats: int, builds: tuple = ("shared",)) -> dict:
    bench = str(ROOT / "bench")
    out = {}
    for name, tree in (("this", ROOT), ("base", base)):
        res = {"loadavg_before": os.getloadavg()[0]}
        for b in builds:
            if b == "auto" and name == "base":
                continue
            sfx = "" if b == "shared" else f"@{b}"
            if "yardstick" in rows:
                res["yardstick" + sfx] = _run(tree, _YARDSTICK.format(bench=bench, n=repeats, kernels=False),
                                              {"VCIRUN_BUILD": b})
            if "kernels" in rows:
                res["kernels" + sfx] = _run(tree, _YARDSTICK.format(bench=bench, n=repeats, kernels=True),
                                            {"VCIRUN_BUILD": b})
        if "cradle" in rows:
            res["cradle"] = _run(tree, _CRADLE.format(bench=bench))
        if "coldbuild" in rows:
            with tempfile.TemporaryDirectory(prefix="vcirun_cold_") as d:
                res["coldbuild"] = _run(tree, _COLD, {"VCIRUN_CACHE_DIR": d})
        out[name] = res
    return out


def combine(rounds: list[dict]) -> dict:
    """One result of several rounds of `measure`: per yardstick or kernels row, the round of median
    call ratio, with the ratios of every round ("loop_ratios", "call_ratios"); the cradle and the cold
    build, the round of median time, with every round's ("rounds")."""
    out = {}
    for name in rounds[0]:
        res = dict(rounds[0][name])
        for row, y in rounds[0][name].items():
            metric = next((k for k in ("call_ratio", "us_per_smooth_step", "cpu_s")
                           if isinstance(y, dict) and k in y), None)
            if metric is None:
                continue
            ys = sorted((r[name][row] for r in rounds if metric in r[name].get(row, {})), key=lambda x: x[metric])
            res[row] = dict(ys[len(ys) // 2], rounds=[x[metric] for x in ys])
            if metric == "call_ratio":
                res[row].update(loop_ratios=[x["loop_ratio"] for x in ys], call_ratios=[x["call_ratio"] for x in ys])
        out[name] = res
    return out


def report(r: dict, log=print) -> None:
    log("== the loop's targets: this tree against the base (fresh process per tree and row)")
    for name in ("this", "base"):
        t = r[name]
        rows = [(k, ("closed forms" if k.startswith("yardstick") else "generated kernels")
                 + (f", {k.split('@')[1]} build" if "@" in k else ", shared build"))
                for k in t if k.startswith(("yardstick", "kernels"))]
        for row, what in rows:
            y = t.get(row, {})
            if "hand_ms" in y:
                log(f"  {name:4s} hand-written CVA ({what}) {y['hand_ms']:.4f} ms | loop {y['loop_ms']:.4f} ms = "
                    f"x{y['loop_ratio']:.2f} (target <= x{TARGETS['loop_ratio']}) | simulate() {y['call_ms']:.4f} ms = "
                    f"x{y['call_ratio']:.2f} (target <= x{TARGETS['call_ratio']}) | same trajectory: impacts "
                    f"{y['impacts']}/{y['vcirun_impacts']}, |dq| {y['q_diff']:.1e}; module: "
                    f"{y.get('module_build', '?')}")
                if len(y.get("call_ratios", ())) > 1:
                    lr, cr = y["loop_ratios"], y["call_ratios"]
                    log(f"       {len(cr)} rounds: loop x{min(lr):.2f}-x{max(lr):.2f}, simulate() "
                        f"x{min(cr):.2f}-x{max(cr):.2f} (median x{cr[len(cr) // 2]:.2f})")
            elif y:
                log(f"  {name:4s} {row}: {y.get('error')}")
        c = t.get("cradle", {})
        if "us_per_smooth_step" in c:
            log(f"  {name:4s} newton_cradle_100 CVA {c['us_per_smooth_step']:.1f} us per smooth step "
                f"(target <= {TARGETS['cradle_us']:g} us; {c['smooth_steps']} steps, {c['status_smooth']})"
                + _spread(c, "us"))
        elif c:
            log(f"  {name:4s} cradle: {c.get('error')}")
        b = t.get("coldbuild", {})
        if "cpu_s" in b:
            log(f"  {name:4s} cold build, first cart-pendulum CVA simulation, empty cache: {b['cpu_s']:.1f} s CPU "
                f"({b['wall_s']:.1f} s wall at load {t['loadavg_before']:.1f})" + _spread(b, "s"))
        elif b:
            log(f"  {name:4s} coldbuild: {b.get('error')}")


def _spread(row: dict, unit: str) -> str:
    r = row.get("rounds", ())
    return f"; {len(r)} rounds {min(r):.1f}-{max(r):.1f} {unit}" if len(r) > 1 else ""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="/work/main")
    ap.add_argument("--rows", default="yardstick,kernels,cradle,coldbuild")
    ap.add_argument("--repeats", type=int, default=201)
    ap.add_argument("--builds", default="shared,specialized,auto")
    ap.add_argument("--rounds", type=int, default=1)
    a = ap.parse_args(argv)
    r = combine([measure(Path(a.base), a.rows.split(","), a.repeats, tuple(a.builds.split(",")))
                 for _ in range(max(1, a.rounds))])
    report(r)
    print(json.dumps(r))


if __name__ == "__main__":
    main()
