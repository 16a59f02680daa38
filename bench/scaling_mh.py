"""Symbolic cost of the MCVA family's modified-Hamiltonian kernels against the degrees of freedom.

For the n-link pendulum against a wall (n = 1, 2, 4, 8) and MCVAC (SVC, H~ to O(h^3)) and MCVAA
(SVA, O(h^4)): CPU seconds of `vcirun.codegen.mh_kernels.modified_kernels_source` (derivation and
emission; sympy only, no numba) and the size of the generated source, each in a fresh process.
With `--baseline PATH` (a checkout of an older vcirun) the same is measured there in the same run,
interleaved, and the ratios are printed.

    python bench/scaling_mh.py [--baseline=PATH] [--timeout=S] [--output=PATH]
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHILD = r"""
import json, sys, time
from vcirun.mechanics import get_scene
from vcirun.methods.table import resolve_method
from vcirun.codegen.mh_kernels import modified_kernels_source
K, meth = int(sys.argv[1]), sys.argv[2]
s = get_scene(f"n_pendulum_{K}")
ks = resolve_method(meth).kernel_set()
t0 = time.process_time()
src = modified_kernels_source(s, ks)
import vcirun
print(json.dumps({"symbolic_s": time.process_time() - t0, "chars": len(src), "vcirun": vcirun.__file__}))
"""


def run(tree: Path, K: int, meth: str, timeout: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    try:
        # cwd = the tree: `python -c` puts the working directory first on sys.path
        r = subprocess.run([sys.executable, "-c", CHILD, str(K), meth], env=env, text=True, cwd=tree,
                           capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout:.0f} s"}
    if r.returncode != 0:
        return {"error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"exit {r.returncode}"}
    res = json.loads(r.stdout.strip().splitlines()[-1])
    if not Path(res["vcirun"]).resolve().is_relative_to(tree.resolve()):
        raise SystemExit(f"{tree}: the child imported {res['vcirun']}")
    return res


def exponent(xs, ys) -> float:
    lx = [math.log(x) for x in xs]
    ly = [math.log(y) for y in ys]
    mx, my = sum(lx) / len(lx), sum(ly) / len(ly)
    return sum((a - mx) * (b - my) for a, b in zip(lx, ly)) / sum((a - mx) ** 2 for a in lx)


def main(argv):
    opts = dict(a[2:].split("=", 1) for a in argv if a.startswith("--") and "=" in a)
    base = Path(opts["baseline"]) if "baseline" in opts else None
    timeout = float(opts.get("timeout", 600))
    out_path = Path(opts.get("output", ROOT / "results" / "scaling_mh.json"))
    trees = [("current", ROOT)] + ([("baseline", base)] if base else [])
    rows = []
    for meth in ("MCVAC", "MCVAA"):
        for K in (1, 2, 4, 8):
            row = {"method": meth, "n": K}
            for tag, tree in trees:
                row[tag] = run(tree, K, meth, timeout)
            rows.append(row)
            cells = "  ".join(f"{tag}: " + (f"{row[tag]['symbolic_s']:.2f} s, {row[tag]['chars'] / 1e3:.0f} kB"
                                             if "error" not in row[tag] else row[tag]["error"]) for tag, _ in trees)
            print(f"{meth} n = {K}: {cells}", flush=True)
    summary = {}
    for meth in ("MCVAC", "MCVAA"):
        for tag, _ in trees:
            ok = [r for r in rows if r["method"] == meth and "error" not in r[tag]]
            if len(ok) >= 2:
                summary[f"{meth}/{tag}"] = {k: exponent([r["n"] for r in ok], [r[tag][k] for r in ok])
                                            for k in ("symbolic_s", "chars")}
                print(f"exponents vs n, {meth} {tag} (n = {', '.join(str(r['n']) for r in ok)}): symbolic "
                      f"{summary[f'{meth}/{tag}']['symbolic_s']:.2f}, source {summary[f'{meth}/{tag}']['chars']:.2f}")
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text(json.dumps({"rows": rows, "exponents": summary}, indent=1))
    print(f"saved {out_path}")


if __name__ == "__main__":
    main(sys.argv[1:])
