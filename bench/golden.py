"""Golden trajectories: capture a set of runs through the public API, or compare against a capture.

    python bench/golden.py capture OUT.npz [--build shared|specialized]
    python bench/golden.py compare OUT.npz [--build shared|specialized] [--tol 1e-10] [--tier interpreted]

The cases cover every collision integrator on the paper's two scenes at two steps, forcing, several
contacts and held contacts. `compare` prints the largest difference of q, p, H, impact times and
impulses per case and exits 1 if any exceeds --tol (or an impact count or status differs). Use it
to check that a restructuring of the code leaves every trajectory where it was.
"""
from __future__ import annotations

import argparse
import os
import sys
import warnings

import numpy as np

CASES = [
    *[(s, m, h, T, {"beta": b}) for s, T, b in (("cart_pendulum", 5.0, 3.2), ("double_pendulum", 5.0, 1.0))
      for m in ("CVA", "VCI", "MCVAA", "MCVAC", "CVA6") for h in (0.05, 0.01)],
    ("damped_oscillator", "CVA", 0.01, 5.0, {}),
    ("damped_oscillator", "MCVAC", 0.01, 5.0, {}),
    ("bouncing_ball", "CVA", 0.01, 3.0, {"params": {"c": 0.3}}),
    ("bouncing_ball", "VCI", 0.01, 3.0, {"params": {"c": 0.3}}),
    ("ball_in_box", "CVA", 0.01, 3.0, {"params": {"e": 0.9}}),
    ("ball_in_box", "MCVAA", 0.01, 3.0, {}),
    ("newton_cradle_3", "CVA", 0.01, 1.0, {}),
    ("newton_cradle_3", "VCI", 0.01, 1.0, {}),
    ("double_pendulum_walls", "MCVAC", 0.01, 3.0, {"beta": 3.0}),
    ("double_pendulum_walls", "CVA", 0.01, 3.0, {"beta": 3.0, "params": {"e": 0.8}}),
    ("bouncing_ball", "CVA", 0.01, 3.0, {"q0": [1.0], "p0": [0.0], "params": {"c": 0.0}}),
    ("bouncing_ball", "MCVAC", 0.02, 4.0, {"params": {"c": 0.5}}),
]
FIELDS = ("q", "p", "H", "impacts", "impact_impulse", "contact_force")


def key(case) -> str:
    s, m, h, T, kw = case
    return f"{s}|{m}|{h}|{T}|{sorted(kw.items())}"


def run(case, tier="compiled"):
    import vcirun

    s, m, h, T, kw = case
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tr = vcirun.simulate(s, m, h=h, T=T, tier=tier, **kw)
    out = {f: np.asarray(getattr(tr, f, np.zeros(0)), dtype=float) for f in FIELDS}
    out["status"] = np.array(tr.status)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mode", choices=("capture", "compare"))
    ap.add_argument("path")
    ap.add_argument("--build", choices=("shared", "specialized"), default="shared")
    ap.add_argument("--tol", type=float, default=1e-10)
    ap.add_argument("--tier", choices=("compiled", "interpreted"), default="compiled",
                    help="the kernels' tier (vcirun.codegen.tiers): golden trajectories are the compiled tier's")
    a = ap.parse_args(argv)
    os.environ["VCIRUN_BUILD"] = a.build   # (pinned: the auto build could switch a case mid-run)
    if a.mode == "capture":
        data = {}
        for c in CASES:
            r = run(c, a.tier)
            for f, v in r.items():
                data[f"{key(c)}::{f}"] = v
            print(f"captured {key(c)}: {r['status']}", flush=True)
        np.savez(a.path, **data)
        return 0
    gold = np.load(a.path)
    worst, bad = 0.0, []
    for c in CASES:
        r = run(c, a.tier)
        k = key(c)
        if str(gold[f"{k}::status"]) != str(r["status"]):
            bad.append(f"{k}: status {gold[f'{k}::status']} -> {r['status']}")
            continue
        diffs = []
        for f in FIELDS:
            g, v = gold[f"{k}::{f}"], r[f]
            if g.shape != v.shape:
                bad.append(f"{k}: {f} shape {g.shape} -> {v.shape}")
                break
            d = float(np.nanmax(np.abs(g - v))) if g.size else 0.0
            diffs.append(d)
        else:
            d = max(diffs)
            worst = max(worst, d)
            print(f"{k}: max diff {d:.3g}", flush=True)
            if d > a.tol:
                bad.append(f"{k}: max diff {d:.3g} > {a.tol:g}")
    print(f"worst difference {worst:.3g} over {len(CASES)} cases ({a.build} build)")
    for b in bad:
        print("MISMATCH", b)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    sys.exit(main())
